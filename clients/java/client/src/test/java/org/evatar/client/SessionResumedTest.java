package org.evatar.client;

import static org.junit.jupiter.api.Assertions.assertEquals;
import static org.junit.jupiter.api.Assertions.assertInstanceOf;
import static org.junit.jupiter.api.Assertions.assertNotNull;
import static org.junit.jupiter.api.Assertions.assertThrows;
import static org.junit.jupiter.api.Assertions.assertTrue;

import java.io.InputStream;
import java.io.OutputStream;
import java.net.Socket;
import java.nio.charset.StandardCharsets;
import java.time.Duration;
import java.util.List;
import java.util.concurrent.CopyOnWriteArrayList;
import java.util.concurrent.TimeUnit;
import java.util.concurrent.atomic.AtomicInteger;
import org.junit.jupiter.api.AfterAll;
import org.junit.jupiter.api.BeforeAll;
import org.junit.jupiter.api.Test;
import org.junit.jupiter.api.Timeout;

/**
 * A second holder of a version 2 session's SessionID (a raw socket sending a
 * Resume) takes the session over: the client ends with reason
 * {@code SessionResumed}, told once, and never resumes again
 * (docs/protocol.md section 11.3 rule 5), against a real node.
 */
@Timeout(value = 60, unit = TimeUnit.SECONDS)
class SessionResumedTest {
    static LocalNode node;
    static final Duration T = Duration.ofSeconds(10);

    @BeforeAll
    static void startNode() throws Exception {
        node = LocalNode.start(Pairings.specs("resumed"));
    }

    @AfterAll
    static void stopNode() {
        if (node != null) {
            node.close();
        }
    }

    @Test
    void sessionResumedElsewhereIsFinal() throws Exception {
        AtomicInteger reconnected = new AtomicInteger();
        List<String> closed = new CopyOnWriteArrayList<>();
        EvatarClient.Listener listener = new EvatarClient.Listener() {
            @Override
            public void onReconnected(String endpoint, boolean resumed, long epoch) {
                reconnected.incrementAndGet();
            }

            @Override
            public void onClosed(String reason, Throwable cause) {
                closed.add(reason + "/" + (cause instanceof RefusedException r ? r.code() : cause));
            }
        };
        try (EvatarClient av = EvatarClient.connect(Pairings.opts(node, "resumed", "avatar", "lamp"), null);
             EvatarClient a = EvatarClient.connect(
                     Pairings.opts(node, "resumed", "agent", "va").ha(true)
                             .handshakeTimeout(Duration.ofSeconds(1)), listener)) {
            av.describe(Bodies.avatar("lamp"));
            a.describe(Bodies.va("va"));
            av.awaitBinding(x -> !x.consumedBy("lamp", "HallMotionSensor01").isEmpty(), T);
            Control.Welcome w = a.welcome();
            assertTrue(w.isVersion2());
            try (Socket s = new Socket(node.host(), node.port())) {
                s.setSoTimeout((int) T.toMillis());
                OutputStream out = s.getOutputStream();
                InputStream in = s.getInputStream();
                Control.Resume resume = new Control.Resume("resumed", "agent", "va", "va-resumed",
                        w.sessionId(), 0, w.epoch());
                Frames.write(out, resume.encode().getBytes(StandardCharsets.UTF_8));
                Control.Welcome again = assertInstanceOf(Control.Welcome.class, next(in));
                assertEquals(Boolean.TRUE, again.resumed());

                assertEquals("SessionResumed", a.awaitClosed(T));
                assertThrows(ClosedException.class, () -> a.send(Signal.builder()
                        .context(Signal.SENSOR_DATA).sender("MotionEmulator01").receiver("HallMotionSensor01")
                        .service("SENSOR", "MotionDetected")));
                // Several heartbeat periods: a client that resumed again would
                // have taken the session back by then (and this socket would be refused).
                Thread.sleep(4 * Math.max(w.heartbeat(), 100));
                assertEquals(List.of("SessionResumed/SessionResumed"), closed);
                assertEquals(0, reconnected.get());
                assertEquals(0, a.reconnects());

                av.send(Signal.builder().context(Signal.SENSOR_DATA).sender("HallMotionSensor01")
                        .receiver("MotionEmulator01").service("SENSOR", "MotionDetected")
                        .param("Motion", "yes").param("Reading", "after"));
                Signal got = nextSignal(in);
                assertEquals("after", got.param("Reading").orElseThrow());
                assertEquals("MotionEmulator01", got.receiver());
            }
        }
    }

    private static Object next(InputStream in) throws Exception {
        return Documents.decode(Frames.read(in, 1 << 20));
    }

    /** The next signal from an entity, past Acks, Binding reports and EVATAR's own signals; a Refused fails. */
    private static Signal nextSignal(InputStream in) throws Exception {
        while (true) {
            Object doc = next(in);
            assertNotNull(doc);
            if (doc instanceof Signal sig && !"EVATAR".equals(sig.sender())) {
                return sig;
            }
            assertTrue(doc instanceof Control.Ack || doc instanceof Control.Binding || doc instanceof Signal,
                    "unexpected " + doc);
        }
    }
}

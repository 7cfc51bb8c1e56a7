package org.evatar.client;

import static org.junit.jupiter.api.Assertions.assertEquals;
import static org.junit.jupiter.api.Assertions.assertFalse;
import static org.junit.jupiter.api.Assertions.assertNotNull;
import static org.junit.jupiter.api.Assertions.assertThrows;
import static org.junit.jupiter.api.Assertions.assertTrue;

import java.io.IOException;
import java.net.ServerSocket;
import java.time.Duration;
import java.util.ArrayList;
import java.util.List;
import java.util.concurrent.CompletableFuture;
import java.util.concurrent.CopyOnWriteArrayList;
import java.util.concurrent.TimeUnit;
import java.util.concurrent.atomic.AtomicBoolean;
import org.junit.jupiter.api.AfterAll;
import org.junit.jupiter.api.BeforeAll;
import org.junit.jupiter.api.Test;
import org.junit.jupiter.api.Timeout;

/** The client against a real EVATAR node started by scripts/test-node.sh. */
@Timeout(value = 60, unit = TimeUnit.SECONDS)
class NodeClientTest {
    static LocalNode node;
    static final Duration T = Duration.ofSeconds(10);

    @BeforeAll
    static void startNode() throws IOException {
        String[] specs = Pairings.specs("join", "req", "timeout", "stream", "cred", "resume", "errors", "occupied",
                "getbinding");
        // "timeout" answers for a silent device after 2 s, not the default 5 s:
        // feedbackTimeoutComesFromEvatar waits for that answer.
        specs[2] += ":2000";
        node = LocalNode.start(specs);
    }

    @AfterAll
    static void stopNode() {
        if (node != null) {
            node.close();
        }
    }

    static EvatarClient.Options opts(String pairing, String role, String entity) {
        return Pairings.opts(node, pairing, role, entity);
    }

    /** An Avatar that answers TurnLightOn/TurnLightOff (unless {@code silent}). */
    static final class Lamp implements EvatarClient.Listener {
        final AtomicBoolean silent = new AtomicBoolean();
        final List<Signal> requests = new CopyOnWriteArrayList<>();
        volatile EvatarClient client;

        @Override
        public void onSignal(Signal s) {
            if (!s.context().equals(Signal.REQUEST)) {
                return;
            }
            requests.add(s);
            if (silent.get()) {
                return;
            }
            try {
                client.send(Signal.builder().context(Signal.PROGRESS).sender(s.receiver()).receiver(s.sender())
                        .inReplyTo(s.id()).service(s.category(), s.type()).param("Percent", "50"));
                client.send(Signal.builder().context(Signal.FEEDBACK).sender(s.receiver()).receiver(s.sender())
                        .inReplyTo(s.id()).service(s.category(), s.type()).param("Done", "yes")
                        .param("Light", s.type().equals("TurnLightOn") ? "on" : "off"));
            } catch (IOException e) {
                throw new IllegalStateException(e);
            }
        }
    }

    static EvatarClient lamp(String pairing, String entity, Lamp l) throws Exception {
        EvatarClient c = EvatarClient.connect(opts(pairing, "avatar", entity), l);
        l.client = c;
        c.describe(Bodies.avatar(entity));
        return c;
    }

    @Test
    void joinAndBindingReport() throws Exception {
        try (EvatarClient va = EvatarClient.connect(opts("join", "agent", "va-1"), null);
             EvatarClient av = lamp("join", "lamp-1", new Lamp())) {
            Control.Welcome w = va.welcome();
            assertEquals("join", w.pairing());
            assertEquals("va-1", w.entityId());
            assertTrue(w.sessionId().matches("[0-9A-Fa-f]{32}"), w.sessionId());
            assertEquals(1048576, w.maxFrame());
            assertFalse(w.isVersion2());
            va.describe(Bodies.va("va-1"));
            Control.Binding b = va.awaitBinding(x -> Bodies.lightBound(x, "va-1"), T);
            assertEquals(List.of("lamp-1", "va-1"), b.entities().stream().sorted().toList());
            // The Avatar hears the same report: its feedback consumer bound to the VA's emulator.
            Control.Binding ab = av.awaitBinding(x -> !x.consumedBy("lamp-1", "HomeLightActuator01").isEmpty(), T);
            assertEquals("LightEmulator01", ab.consumedBy("lamp-1", "HomeLightActuator01").get(0).providerComponent());
            // The sensor consumes the VA's MotionDetected: the direction sensor data flows.
            assertEquals("MotionEmulator01", ab.consumedBy("lamp-1", "HallMotionSensor01").get(0).providerComponent());
        }
    }

    /** GetBinding (docs/protocol.md section 2): the current report comes again, to this client. */
    @Test
    void requestBindingSendsTheReportAgain() throws Exception {
        List<Control.Binding> reports = new CopyOnWriteArrayList<>();
        try (EvatarClient va = EvatarClient.connect(opts("getbinding", "agent", "va-gb"),
                new EvatarClient.Listener() {
                    @Override
                    public void onBinding(Control.Binding b) {
                        reports.add(b);
                    }
                })) {
            va.describe(Bodies.va("va-gb"));
            Control.Binding first = va.awaitBinding(x -> x.entities().equals(List.of("va-gb")), T);
            va.requestBinding();
            long deadline = System.nanoTime() + T.toNanos();
            while (reports.size() < 2 && System.nanoTime() < deadline) {
                Thread.sleep(10);
            }
            assertEquals(List.of(first, first), reports);
        }
    }

    @Test
    void requestGetsProgressThenFeedback() throws Exception {
        Lamp l = new Lamp();
        try (EvatarClient av = lamp("req", "lamp-2", l);
             EvatarClient va = EvatarClient.connect(opts("req", "agent", "va-2"), null)) {
            va.describe(Bodies.va("va-2"));
            va.awaitBinding(x -> Bodies.lightBound(x, "va-2"), T);
            ActuatorEmulator light = new ActuatorEmulator(va, "LightEmulator01");
            Signal fb = light.call("TurnLightOn", List.of(new Param("Light", "yes")), T);
            assertEquals(Signal.FEEDBACK, fb.context());
            assertTrue(fb.isSuccess());
            assertEquals("HomeLightActuator01", fb.sender());
            assertEquals("on", fb.param("Light").orElseThrow());
            assertEquals(1, l.requests.size());
            assertEquals(fb.inReplyTo(), l.requests.get(0).id());
            assertEquals(List.of(new Param("Light", "yes")), l.requests.get(0).parameters());
            // The Progress came first, as a signal for the VA.
            Signal progress = va.receive(T);
            assertNotNull(progress);
            assertEquals(Signal.PROGRESS, progress.context());
            assertEquals(fb.inReplyTo(), progress.inReplyTo());
            assertNotNull(progress.sequence());
            assertTrue(progress.sequence() < fb.sequence());
            // Several requests at once are matched by InReplyTo.
            List<CompletableFuture<Signal>> fs = new ArrayList<>();
            for (int i = 0; i < 10; i++) {
                fs.add(light.request(i % 2 == 0 ? "TurnLightOn" : "TurnLightOff", List.of()));
            }
            for (int i = 0; i < 10; i++) {
                assertEquals(i % 2 == 0 ? "on" : "off", fs.get(i).get(10, TimeUnit.SECONDS).param("Light").orElseThrow());
            }
        }
    }

    @Test
    void feedbackTimeoutComesFromEvatar() throws Exception {
        Lamp l = new Lamp();
        l.silent.set(true);
        try (EvatarClient av = lamp("timeout", "lamp-3", l);
             EvatarClient va = EvatarClient.connect(opts("timeout", "agent", "va-3"), null)) {
            va.describe(Bodies.va("va-3"));
            va.awaitBinding(x -> Bodies.lightBound(x, "va-3"), T);
            ActuatorEmulator light = new ActuatorEmulator(va, "LightEmulator01");
            // Our own wait ends first when shorter than the pairing's deadline...
            assertThrows(java.util.concurrent.TimeoutException.class,
                    () -> light.call("TurnLightOn", List.of(), Duration.ofMillis(300)));
            // ...and EVATAR answers for the silent provider when its deadline passes.
            Signal fb = light.request("TurnLightOff", List.of()).get(20, TimeUnit.SECONDS);
            assertTrue(fb.isTimeout(), fb.toString());
            assertEquals("EVATAR", fb.sender());
            assertFalse(fb.isSuccess());
            assertTrue(fb.param("Message").isPresent());
            assertEquals(2, l.requests.size());
        }
    }

    @Test
    void sensorStreamArrivesInOrder() throws Exception {
        try (EvatarClient av = lamp("stream", "lamp-4", new Lamp())) {
            List<Signal> got = new CopyOnWriteArrayList<>();
            EvatarClient[] holder = new EvatarClient[1];
            SensorEmulator[] motion = new SensorEmulator[1];
            try (EvatarClient va = EvatarClient.connect(opts("stream", "agent", "va-4"), new EvatarClient.Listener() {
                @Override
                public void onSignal(Signal s) {
                    if (!motion[0].offer(s)) {
                        got.add(s);
                    }
                }
            })) {
                holder[0] = va;
                motion[0] = new SensorEmulator(va, "MotionEmulator01");
                va.describe(Bodies.va("va-4"));
                av.awaitBinding(x -> !x.consumedBy("lamp-4", "HallMotionSensor01").isEmpty(), T);
                int n = 200;
                for (int i = 0; i < n; i++) {
                    av.send(Signal.builder().context(Signal.SENSOR_DATA).sender("HallMotionSensor01")
                            .receiver("MotionEmulator01").service("SENSOR", "MotionDetected")
                            .param("Motion", i % 2 == 0 ? "yes" : "no").param("Reading", Integer.toString(i)));
                }
                long lastSeq = 0;
                for (int i = 0; i < n; i++) {
                    Signal s = motion[0].next(T);
                    assertNotNull(s, "reading " + i + " missing");
                    assertEquals(Integer.toString(i), s.param("Reading").orElseThrow());
                    assertEquals("HallMotionSensor01", s.sender());
                    assertTrue(s.sequence() > lastSeq);
                    lastSeq = s.sequence();
                }
                assertEquals(List.of(), got);
            }
        }
    }

    @Test
    void badCredentialIsRefused() {
        RefusedException e = assertThrows(RefusedException.class, () -> EvatarClient.connect(
                opts("cred", "agent", "va-5").credential("wrong"), null));
        assertEquals("BadCredential", e.code());
        RefusedException u = assertThrows(RefusedException.class, () -> EvatarClient.connect(
                opts("no-such-pairing", "agent", "va-5"), null));
        assertEquals("UnknownPairing", u.code());
    }

    @Test
    void secondVaIsRefusedOccupied() throws Exception {
        try (EvatarClient va = EvatarClient.connect(opts("occupied", "agent", "va-6"), null)) {
            RefusedException e = assertThrows(RefusedException.class, () -> EvatarClient.connect(
                    opts("occupied", "agent", "va-6b"), null));
            assertEquals("Occupied", e.code());
            assertEquals(null, va.closedReason());
        }
    }

    @Test
    void errorsComeBackAsSignals() throws Exception {
        try (EvatarClient av = lamp("errors", "lamp-7", new Lamp());
             EvatarClient va = EvatarClient.connect(opts("errors", "agent", "va-7"), null)) {
            // Before any description: NotDescribed.
            CompletableFuture<Signal> early = va.request(Signal.builder().sender("LightEmulator01")
                    .receiver("HomeLightActuator01").service("ACTUATOR", "TurnLightOn"));
            Signal e1 = early.get(10, TimeUnit.SECONDS);
            assertTrue(e1.isError());
            assertEquals("NotDescribed", e1.type());
            va.describe(Bodies.va("va-7"));
            va.awaitBinding(x -> Bodies.lightBound(x, "va-7"), T);
            Signal e2 = va.request(Signal.builder().sender("NoSuchEmulator").receiver("HomeLightActuator01")
                    .service("ACTUATOR", "TurnLightOn")).get(10, TimeUnit.SECONDS);
            assertEquals("BadSender", e2.type());
            Signal e3 = va.request(Signal.builder().sender("LightEmulator01").receiver("Nobody")
                    .service("ACTUATOR", "TurnLightOn")).get(10, TimeUnit.SECONDS);
            assertEquals("UnknownReceiver", e3.type());
            assertTrue(e3.param("Message").isPresent());
        }
    }

    @Test
    void reconnectsAndResumesAfterADroppedConnection() throws Exception {
        int dead;
        try (ServerSocket s = new ServerSocket(0)) {
            dead = s.getLocalPort();
        }
        Lamp l = new Lamp();
        List<String> reconnects = new CopyOnWriteArrayList<>();
        List<Signal> readings = new CopyOnWriteArrayList<>();
        try (EvatarClient av = lamp("resume", "lamp-8", l);
             EvatarClient va = EvatarClient.connect(
                     opts("resume", "agent", "va-8").ha(true).endpoint("127.0.0.1", dead)
                             .handshakeTimeout(Duration.ofSeconds(1)),
                     new EvatarClient.Listener() {
                         @Override
                         public void onSignal(Signal s) {
                             if (s.context().equals(Signal.SENSOR_DATA)) {
                                 readings.add(s);
                             }
                         }

                         @Override
                         public void onReconnected(String endpoint, boolean resumed, long epoch) {
                             reconnects.add(endpoint + " resumed=" + resumed + " epoch=" + epoch);
                         }
                     })) {
            Control.Welcome w = va.welcome();
            assertTrue(w.isVersion2());
            assertEquals(Boolean.FALSE, w.resumed());
            va.describe(Bodies.va("va-8"));
            va.awaitBinding(x -> Bodies.lightBound(x, "va-8"), T);
            ActuatorEmulator light = new ActuatorEmulator(va, "LightEmulator01");
            assertEquals("on", light.call("TurnLightOn", List.of(), T).param("Light").orElseThrow());
            assertTrue(va.awaitAcks(T));
            String session = w.sessionId();

            va.dropConnection();
            // While the VA is away its session stays; what is sent to it is kept.
            for (int i = 0; i < 20; i++) {
                av.send(Signal.builder().context(Signal.SENSOR_DATA).sender("HallMotionSensor01")
                        .receiver("MotionEmulator01").service("SENSOR", "MotionDetected")
                        .param("Reading", Integer.toString(i)));
            }
            // A request sent while disconnected goes once the session is back.
            CompletableFuture<Signal> off = light.request("TurnLightOff", List.of());
            assertEquals("off", off.get(20, TimeUnit.SECONDS).param("Light").orElseThrow());
            long end = System.nanoTime() + TimeUnit.SECONDS.toNanos(10);
            while (readings.size() < 20 && System.nanoTime() < end) {
                Thread.sleep(20);
            }
            assertEquals(20, readings.size(), "readings: " + readings.size());
            for (int i = 0; i < 20; i++) {
                assertEquals(Integer.toString(i), readings.get(i).param("Reading").orElseThrow());
            }
            assertTrue(va.reconnects() >= 1);
            assertTrue(reconnects.get(0).contains("resumed=true"), reconnects.toString());
            assertEquals(session, va.welcome().sessionId());
            assertTrue(va.awaitAcks(T));
            assertEquals(0, va.unacknowledged());
            // Each request reached the lamp exactly once.
            assertEquals(List.of("TurnLightOn", "TurnLightOff"), l.requests.stream().map(Signal::type).toList());
            assertEquals(null, va.closedReason());
        }
    }
}

package org.evatar.client;

import static org.junit.jupiter.api.Assertions.assertEquals;
import static org.junit.jupiter.api.Assertions.assertFalse;
import static org.junit.jupiter.api.Assertions.assertNotNull;
import static org.junit.jupiter.api.Assertions.assertNull;
import static org.junit.jupiter.api.Assertions.assertThrows;
import static org.junit.jupiter.api.Assertions.assertTrue;

import java.io.DataInputStream;
import java.io.IOException;
import java.io.InputStream;
import java.net.InetAddress;
import java.net.InetSocketAddress;
import java.net.ServerSocket;
import java.net.Socket;
import java.net.SocketTimeoutException;
import java.nio.file.Files;
import java.nio.file.Path;
import java.time.Duration;
import java.util.ArrayList;
import java.util.List;
import java.util.concurrent.CompletableFuture;
import java.util.concurrent.CopyOnWriteArrayList;
import java.util.concurrent.CountDownLatch;
import java.util.concurrent.ExecutionException;
import java.util.concurrent.TimeUnit;
import java.util.function.BooleanSupplier;
import java.util.stream.Stream;
import org.junit.jupiter.api.AfterAll;
import org.junit.jupiter.api.BeforeAll;
import org.junit.jupiter.api.Test;
import org.junit.jupiter.api.Timeout;

/**
 * The client's lifecycle against a real node over real TCP: close twice,
 * close during the TCP connect and during the handshake, refused connects in
 * a loop that leave no thread or socket behind, reconnecting with the same
 * EntityID right after close, connect on a connected client, the errors of
 * an emulator whose service is not bound, and the accepted-signal notices.
 * The node's listener has no handshake guard (many refusals in seconds).
 */
@Timeout(value = 120, unit = TimeUnit.SECONDS)
class LifecycleTest {
    static LocalNode node;
    static final Duration T = Duration.ofSeconds(10);

    @BeforeAll
    static void startNode() throws IOException {
        node = LocalNode.startWithoutGuard(Pairings.specs("twice", "refused", "cycles", "cycles2", "again", "acks", "bound",
                "away"));
    }

    @AfterAll
    static void stopNode() {
        if (node != null) {
            node.close();
        }
    }

    static EvatarClient.Options unreachable(int port) {
        return new EvatarClient.Options().pairing("p").role("agent").entityId("lc-va")
                .credential("x").endpoint("127.0.0.1", port);
    }

    /** The threads (reader, acknowledgements) of this class's clients (EntityIDs lc-...) alive now. */
    static List<String> clientThreads() {
        return Thread.getAllStackTraces().keySet().stream().filter(Thread::isAlive).map(Thread::getName)
                .filter(n -> n.startsWith("evatar-") && n.contains("-lc-")).sorted().toList();
    }

    static long openFds() throws IOException {
        try (Stream<Path> s = Files.list(Path.of("/proc/self/fd"))) {
            return s.count();
        }
    }

    /**
     * No descriptor left behind: the count comes back to at most {@code before}
     * within 20 s (the JVM's own descriptors come and go: fewer is not a leak,
     * one read of a changing count is not compared for equality, and the
     * verdict is the read that ended the wait, not a second one: a JVM
     * descriptor opened between two reads failed a clean-clone run).
     */
    static void assertNoMoreFds(long before) throws Exception {
        long end = System.nanoTime() + TimeUnit.SECONDS.toNanos(20);
        long after = openFds();
        while (after > before && System.nanoTime() < end) {
            Thread.sleep(20);
            after = openFds();
        }
        assertTrue(after <= before, "open descriptors: " + before + " before, " + after + " after");
    }

    static void waitUntil(BooleanSupplier c) throws InterruptedException {
        long end = System.nanoTime() + TimeUnit.SECONDS.toNanos(20);
        while (!c.getAsBoolean() && System.nanoTime() < end) {
            Thread.sleep(20);
        }
    }

    /** Runs {@code c.connect()} on a thread of its own; the future has its exception. */
    static CompletableFuture<Void> connectAsync(EvatarClient c) {
        CompletableFuture<Void> f = new CompletableFuture<>();
        Thread th = new Thread(() -> {
            try {
                c.connect();
                f.complete(null);
            } catch (Throwable e) {
                f.completeExceptionally(e);
            }
        }, "test-connect");
        th.setDaemon(true);
        th.start();
        return f;
    }

    static Throwable failure(CompletableFuture<Void> f) throws Exception {
        ExecutionException e = assertThrows(ExecutionException.class, () -> f.get(10, TimeUnit.SECONDS));
        return e.getCause();
    }

    @Test
    void closeTwice() throws Exception {
        List<String> closed = new CopyOnWriteArrayList<>();
        EvatarClient va = EvatarClient.connect(Pairings.opts(node, "twice", "agent", "lc-va-t"), new EvatarClient.Listener() {
            @Override
            public void onClosed(String reason, Throwable cause) {
                closed.add(reason);
            }
        });
        va.close();
        va.close();
        assertEquals("closed", va.closedReason());
        assertEquals(List.of("closed"), closed);
        assertEquals(List.of(), clientThreads());
        ClosedException e = assertThrows(ClosedException.class,
                () -> va.send(Signal.builder().sender("LightEmulator01").receiver("x").service("ACTUATOR", "X")));
        assertEquals("closed", e.reason());
        // try-with-resources after an explicit close: a third close, no exception.
        try (EvatarClient c = va) {
            assertNotNull(c.closedReason());
        }
    }

    @Test
    void closeBeforeConnect() throws Exception {
        EvatarClient c = EvatarClient.create(Pairings.opts(node, "twice", "agent", "lc-va-n"), null);
        assertThrows(IllegalStateException.class,
                () -> c.send(Signal.builder().sender("LightEmulator01").receiver("x").service("ACTUATOR", "X")));
        c.close();
        c.close();
        assertThrows(ClosedException.class, c::connect);
        assertEquals(List.of(), clientThreads());
    }

    /** close() while the TCP connect waits (a listener whose accept queue is full drops the SYN). */
    @Test
    void closeDuringTcpConnect() throws Exception {
        try (ServerSocket full = new ServerSocket(0, 1, InetAddress.getLoopbackAddress())) {
            List<Socket> fillers = new ArrayList<>();
            try {
                while (fillers.size() < 64) {
                    Socket s = new Socket();
                    try {
                        s.connect(new InetSocketAddress("127.0.0.1", full.getLocalPort()), 300);
                        fillers.add(s);
                    } catch (SocketTimeoutException e) {
                        s.close();
                        break;
                    }
                }
                EvatarClient c = EvatarClient.create(unreachable(full.getLocalPort())
                        .connectTimeout(Duration.ofSeconds(600)), null);
                CompletableFuture<Void> f = connectAsync(c);
                waitUntil(c::isOpening);
                assertTrue(c.isOpening());
                assertFalse(f.isDone());
                c.close();
                assertTrue(failure(f) instanceof ClosedException, String.valueOf(f));
                assertFalse(c.isOpening());
                assertEquals("closed", c.closedReason());
            } finally {
                for (Socket s : fillers) {
                    s.close();
                }
            }
        }
    }

    /** A listener of one connection that reads the Hello, says so, and answers {@code answer} when told. */
    static final class FakeServer implements AutoCloseable {
        final ServerSocket ss = new ServerSocket(0, 50, InetAddress.getLoopbackAddress());
        final CountDownLatch hello = new CountDownLatch(1);
        final CountDownLatch answer = new CountDownLatch(1);
        final CompletableFuture<Boolean> peerClosed = new CompletableFuture<>();
        final Thread th;

        FakeServer(byte[] reply) throws IOException {
            th = new Thread(() -> {
                try (Socket s = ss.accept()) {
                    DataInputStream in = new DataInputStream(s.getInputStream());
                    in.readFully(new byte[in.readInt()]);
                    hello.countDown();
                    if (reply != null) {
                        answer.await();
                        try {
                            Frames.write(s.getOutputStream(), reply);
                        } catch (IOException e) {
                            // The client has gone: what the test wants.
                        }
                    }
                    InputStream raw = s.getInputStream();
                    peerClosed.complete(raw.read() < 0);
                } catch (Exception e) {
                    peerClosed.complete(true);  // a reset is a close too
                }
            }, "fake-server");
            th.setDaemon(true);
            th.start();
        }

        int port() {
            return ss.getLocalPort();
        }

        @Override
        public void close() throws IOException {
            ss.close();
        }
    }

    /** close() while the server accepted and never answers the Hello. */
    @Test
    void closeDuringSilentHandshake() throws Exception {
        try (FakeServer srv = new FakeServer(null)) {
            EvatarClient c = EvatarClient.create(unreachable(srv.port())
                    .handshakeTimeout(Duration.ofSeconds(600)), null);
            CompletableFuture<Void> f = connectAsync(c);
            assertTrue(srv.hello.await(10, TimeUnit.SECONDS));
            c.close();
            assertTrue(failure(f) instanceof ClosedException);
            assertTrue(srv.peerClosed.get(10, TimeUnit.SECONDS));
            assertEquals(List.of(), clientThreads());
        }
    }

    /** close() while the Welcome is on its way: it comes after close() was called and is dropped. */
    @Test
    void closeDuringLateWelcome() throws Exception {
        byte[] welcome = ("<bil:Welcome xmlns:bil=\"urn:evatar:bil:1\"><Pairing>p</Pairing>"
                + "<EntityID>lc-va</EntityID><SessionID>" + "A".repeat(32) + "</SessionID>"
                + "<JoinTimeout>2000</JoinTimeout><MaxFrame>1048576</MaxFrame></bil:Welcome>")
                .getBytes(java.nio.charset.StandardCharsets.UTF_8);
        try (FakeServer srv = new FakeServer(welcome)) {
            EvatarClient c = EvatarClient.create(unreachable(srv.port()), null);
            CompletableFuture<Void> f = connectAsync(c);
            assertTrue(srv.hello.await(10, TimeUnit.SECONDS));
            c.close();
            srv.answer.countDown();
            assertTrue(failure(f) instanceof ClosedException);
            assertTrue(srv.peerClosed.get(10, TimeUnit.SECONDS));
            assertEquals("closed", c.closedReason());
            assertNull(c.welcome());
            assertEquals(List.of(), clientThreads());
        }
    }

    /**
     * Version 2: close() while the client reconnects on its own and waits in
     * a handshake that never ends (the next endpoint accepts and stays
     * silent): it ends that handshake and returns with no thread left.
     */
    @Test
    void closeDuringReconnect() throws Exception {
        try (FakeServer srv = new FakeServer(null)) {
            List<String> closed = new CopyOnWriteArrayList<>();
            EvatarClient va = EvatarClient.connect(Pairings.opts(node, "away", "agent", "lc-va-w").ha(true)
                    .endpoint("127.0.0.1", srv.port()).handshakeTimeout(Duration.ofSeconds(600)),
                    new EvatarClient.Listener() {
                        @Override
                        public void onClosed(String reason, Throwable cause) {
                            closed.add(reason);
                        }
                    });
            va.dropConnection();
            assertTrue(srv.hello.await(10, TimeUnit.SECONDS));
            assertNull(va.closedReason());
            va.close();
            assertEquals("closed", va.closedReason());
            assertEquals(List.of("closed"), closed);
            assertEquals(List.of(), clientThreads());
            assertTrue(srv.peerClosed.get(10, TimeUnit.SECONDS));
        }
    }

    @Test
    void connectConnectedClientFailsLocally() throws Exception {
        try (EvatarClient va = EvatarClient.connect(Pairings.opts(node, "again", "agent", "lc-va-a"), null)) {
            String session = va.welcome().sessionId();
            IllegalStateException e = assertThrows(IllegalStateException.class, va::connect);
            assertTrue(e.getMessage().contains("already connected"), e.getMessage());
            assertEquals(session, va.welcome().sessionId());
            assertNull(va.closedReason());
        }
        try (FakeServer srv = new FakeServer(null)) {
            EvatarClient c = EvatarClient.create(unreachable(srv.port())
                    .handshakeTimeout(Duration.ofSeconds(600)), null);
            CompletableFuture<Void> f = connectAsync(c);
            assertTrue(srv.hello.await(10, TimeUnit.SECONDS));
            IllegalStateException e = assertThrows(IllegalStateException.class, c::connect);
            assertTrue(e.getMessage().contains("already connecting"), e.getMessage());
            c.close();
            assertTrue(failure(f) instanceof ClosedException);
        }
    }

    /** 100 connects with a wrong credential: each refused, no thread or file descriptor left. */
    @Test
    void refusedLoopLeavesNothing() throws Exception {
        EvatarClient.Options wrong = Pairings.opts(node, "refused", "agent", "lc-va-r").credential("wrong");
        // One round first, so classes and the JDK's own descriptors are there.
        assertThrows(RefusedException.class, () -> EvatarClient.connect(wrong, null));
        long fds = openFds();
        List<String> codes = new ArrayList<>();
        for (int i = 0; i < 100; i++) {
            RefusedException e = assertThrows(RefusedException.class, () -> EvatarClient.connect(wrong, null));
            codes.add(e.code());
        }
        assertEquals(List.of("BadCredential"), codes.stream().distinct().toList());
        assertEquals(List.of(), clientThreads());
        assertNoMoreFds(fds);
        // The same with version 2, whose client has an acknowledgement thread once connected.
        for (int i = 0; i < 20; i++) {
            assertThrows(RefusedException.class, () -> EvatarClient.connect(wrong.ha(true), null));
        }
        assertEquals(List.of(), clientThreads());
        assertNoMoreFds(fds);
    }

    /** 50 close/connect cycles with one EntityID: none refused EntityExists (close waits for the Bye). */
    @Test
    void reconnectSameIdAfterClose() throws Exception {
        cycles("cycles", false);
    }

    @Test
    void reconnectSameIdAfterCloseVersion2() throws Exception {
        cycles("cycles2", true);
    }

    static void cycles(String pairing, boolean ha) throws Exception {
        long fds = -1;
        List<String> refused = new ArrayList<>();
        for (int i = 0; i < 50; i++) {
            try {
                EvatarClient c = EvatarClient.connect(Pairings.opts(node, pairing, "agent", "lc-va-c").ha(ha), null);
                c.close();
            } catch (RefusedException e) {
                refused.add(e.code());
            }
            if (i == 0) {
                fds = openFds();
            }
        }
        assertEquals(List.of(), refused);
        assertEquals(List.of(), clientThreads());
        assertNoMoreFds(fds);
    }

    /** Version 2: the listener is told which signals EVATAR accepted, by SignalID, each once, in order. */
    @Test
    void acceptedSignalsAreTold() throws Exception {
        List<String> accepted = new CopyOnWriteArrayList<>();
        try (EvatarClient va = EvatarClient.connect(Pairings.opts(node, "acks", "agent", "lc-va-k"), null);
             EvatarClient av = EvatarClient.connect(Pairings.opts(node, "acks", "avatar", "lc-av-k").ha(true),
                     new EvatarClient.Listener() {
                         @Override
                         public void onAccepted(List<String> ids) {
                             accepted.addAll(ids);
                         }
                     })) {
            va.describe(Bodies.va("lc-va-k"));
            av.describe(Bodies.avatar("lc-av-k"));
            va.awaitBinding(b -> Bodies.lightBound(b, "lc-va-k"), T);
            List<String> sent = new ArrayList<>();
            for (int i = 0; i < 20; i++) {
                sent.add(av.send(Signal.builder().context(Signal.SENSOR_DATA).sender("HallMotionSensor01")
                        .receiver("MotionEmulator01").service("SENSOR", "MotionDetected")
                        .param("N", Integer.toString(i))));
            }
            assertTrue(av.awaitAcks(T));
            waitUntil(() -> accepted.size() >= sent.size());
            assertEquals(sent, accepted);
        }
    }

    /** An emulator's request with nothing to address fails locally with NotBoundException, saying why. */
    @Test
    void notBoundErrors() throws Exception {
        try (EvatarClient va = EvatarClient.connect(Pairings.opts(node, "bound", "agent", "lc-va-b"), null)) {
            ActuatorEmulator light = new ActuatorEmulator(va, "LightEmulator01");
            NotBoundException early = assertThrows(NotBoundException.class,
                    () -> light.call("TurnLightOn", List.of(), T));
            assertEquals(NotBoundException.Why.NO_BINDING_REPORT, early.why());
            va.describe(Bodies.va("lc-va-b"));
            NotBoundException notConsumed = assertThrows(NotBoundException.class,
                    () -> light.call("OpenDoor", List.of(), T));
            assertEquals(NotBoundException.Why.NOT_CONSUMED, notConsumed.why());
            assertEquals("OpenDoor", notConsumed.type());
            va.awaitBinding(b -> b.entities().contains("lc-va-b"), T);
            NotBoundException unbound = assertThrows(NotBoundException.class,
                    () -> light.call("TurnLightOn", List.of(), T));
            assertEquals(NotBoundException.Why.UNBOUND, unbound.why());
            assertEquals("LightEmulator01", unbound.component());
        }
    }
}

package org.evatar.client;

import java.io.EOFException;
import java.io.IOException;
import java.net.InetSocketAddress;
import java.net.Socket;
import java.net.SocketException;
import java.net.SocketTimeoutException;
import java.time.Duration;
import java.util.ArrayList;
import java.util.Iterator;
import java.util.LinkedHashMap;
import java.util.List;
import java.util.Map;
import java.util.Objects;
import java.util.concurrent.BlockingQueue;
import java.util.concurrent.CompletableFuture;
import java.util.concurrent.ConcurrentHashMap;
import java.util.concurrent.ExecutionException;
import java.util.concurrent.LinkedBlockingQueue;
import java.util.concurrent.TimeUnit;
import java.util.concurrent.TimeoutException;
import java.util.concurrent.atomic.AtomicLong;
import java.util.function.Predicate;
import javax.net.ssl.SSLHandshakeException;

/**
 * A VA or an Avatar connected to EVATAR (docs/protocol.md): the handshake,
 * descriptions, signals, requests awaiting feedback, and with
 * {@link Options#ha(boolean)} protocol version 2 (acknowledgements, resume,
 * several endpoints, reconnect). One reader thread per client; every method
 * is thread-safe.
 *
 * <p>Incoming signals go to the {@link Listener}; without one they wait in an
 * inbox read with {@link #receive(Duration)}. Feedback answering a
 * {@link #request} completes that request instead.
 *
 * <p>{@link #connect(Options, Listener)} connects at once. {@link #create}
 * makes a client that {@link #connect()} connects later, so another thread
 * can {@link #close()} it while it connects. {@link #close()} may be called
 * at any time, any number of times: it stops a connect in progress, says Bye
 * and waits (at most {@link Options#closeTimeout(Duration)}, 5 s by default)
 * for EVATAR's Bye, so the same EntityID can connect again at once, and
 * returns once the client's threads and socket are gone.
 */
public final class EvatarClient implements AutoCloseable {

    /** What the client tells its owner. Every method runs on the reader thread: do not block long. */
    public interface Listener {
        default void onSignal(Signal signal) {}

        default void onBinding(Control.Binding binding) {}

        /** Version 2: the session continued (or started again) on {@code endpoint}. */
        default void onReconnected(String endpoint, boolean resumed, long epoch) {}

        /** The client is closed for good: {@code reason} is {@code bye}, {@code closed}, a Refused code... */
        default void onClosed(String reason, Throwable cause) {}

        /**
         * Version 2: EVATAR accepted these signals (their SignalIDs, in the
         * order they were sent), each told once. A signal accepted is kept
         * by EVATAR; one never told here may be lost when the client closes.
         */
        default void onAccepted(List<String> signalIds) {}
    }

    /** Options of a connection; {@code pairing}, {@code role}, {@code entityId} are required. */
    public static final class Options {
        String pairing;
        String role = "agent";
        String entityId;
        String credential = "";
        final List<InetSocketAddress> endpoints = new ArrayList<>();
        boolean ha;
        int connectTimeoutMs = 5000;
        int handshakeTimeoutMs = 5000;
        int closeTimeoutMs = 5000;
        int backoffMinMs = 20;
        int backoffMaxMs = 500;
        long reconnectLimitMs = 600000;
        Tls tls;

        public Options pairing(String v) { pairing = v; return this; }
        /** {@code agent} (a VA) or {@code avatar}. */
        public Options role(String v) { role = v; return this; }
        public Options entityId(String v) { entityId = v; return this; }
        public Options credential(String v) { credential = v; return this; }
        public Options endpoint(String host, int port) { endpoints.add(new InetSocketAddress(host, port)); return this; }
        /** Speak protocol version 2: acknowledgements, resume and reconnect to the next endpoint. */
        public Options ha(boolean v) { ha = v; return this; }
        public Options connectTimeout(Duration d) { connectTimeoutMs = (int) d.toMillis(); return this; }
        /** Keep it small with several endpoints: a stopped node may still accept TCP connections. */
        public Options handshakeTimeout(Duration d) { handshakeTimeoutMs = (int) d.toMillis(); return this; }
        public Options reconnectBackoff(Duration min, Duration max) {
            backoffMinMs = (int) min.toMillis();
            backoffMaxMs = (int) max.toMillis();
            return this;
        }
        /** How long {@link EvatarClient#close()} waits for EVATAR's Bye (default 5 s). */
        public Options closeTimeout(Duration d) { closeTimeoutMs = (int) d.toMillis(); return this; }
        /** Connect with TLS and check the server ({@link Tls}); default plain TCP. */
        public Options tls(Tls v) { tls = v; return this; }
        /** How long to go without a session before giving up ({@code gave_up}). */
        public Options reconnectLimit(Duration d) { reconnectLimitMs = d.toMillis(); return this; }

        void check() {
            Objects.requireNonNull(pairing, "pairing");
            Objects.requireNonNull(entityId, "entityId");
            if (!role.equals("agent") && !role.equals("avatar")) {
                throw new IllegalArgumentException("role must be agent or avatar: " + role);
            }
        }
    }

    /** Refused codes after which a version 2 client tries its next endpoint (section 11.3). */
    private static final List<String> RETRY_CODES = List.of("NotActive", "Fenced", "StaleEpoch",
            "PairingDown", "UnknownPairing", "HandshakeTimeout", "SilentLink", "SessionResumed",
            "Busy", "TooManyConnections", "RateLimited");
    private static final int ACK_EVERY = 32;
    private static final long ACK_DELAY_MS = 5;

    private final Options opts;
    private final Listener listener;
    private final BlockingQueue<Signal> inbox = new LinkedBlockingQueue<>();
    private final Map<String, CompletableFuture<Signal>> pending = new ConcurrentHashMap<>();
    private final Object lock = new Object();
    private final AtomicLong counter = new AtomicLong();
    private final String idPrefix;
    private final boolean stdio;

    // Guarded by lock.
    private Transport transport;
    private int endpointIndex;
    private Control.Welcome welcome;
    private String sessionId;
    private Description description;
    private Control.Binding binding;
    private final LinkedHashMap<String, byte[]> unacked = new LinkedHashMap<>();
    /* After a new session on a reconnect (the server lost the old one, e.g.
       every node restarted), signals wait until a Binding report shows
       another entity registered, instead of being refused as UnknownReceiver. */
    private boolean held;
    private long highestSeq;
    private long highestEpoch;
    private long lastAckedSeq;
    private long maxFrame = Frames.HANDSHAKE_MAX;
    private boolean closing;
    private String closedReason;
    private int reconnects;
    /* The socket being connected or in its handshake, for close() to end. */
    private Socket opening;
    /* A thread is in connect(); connectedOnce: a Welcome came once. */
    private boolean connecting;
    private boolean connectedOnce;
    /* SignalIDs accepted, not told to the listener yet. */
    private final List<String> acceptedToTell = new ArrayList<>();

    private final Thread reader;
    private final Thread acker;

    private EvatarClient(Options opts, Listener listener, boolean stdio) {
        this.opts = opts;
        this.listener = listener;
        this.stdio = stdio;
        this.idPrefix = opts.entityId + "-" + Long.toHexString(System.nanoTime() & 0xffffffL) + "-";
        this.reader = new Thread(this::readLoop, "evatar-client-" + opts.entityId);
        this.reader.setDaemon(true);
        this.acker = new Thread(this::ackLoop, "evatar-acks-" + opts.entityId);
        this.acker.setDaemon(true);
    }

    /**
     * Connects over TCP to the first endpoint that welcomes the client (each
     * is tried in order) and returns once the Welcome arrived:
     * {@link #create} then {@link #connect()}.
     *
     * @throws RefusedException EVATAR refused (BadCredential, Occupied...)
     * @throws IOException no endpoint could be reached
     */
    public static EvatarClient connect(Options opts, Listener listener) throws IOException, ProtocolException {
        EvatarClient c = create(opts, listener);
        c.connect();
        return c;
    }

    /** A client that is not connected yet: {@link #connect()} connects it. */
    public static EvatarClient create(Options opts, Listener listener) {
        opts.check();
        if (opts.endpoints.isEmpty()) {
            throw new IllegalArgumentException("no endpoint");
        }
        return new EvatarClient(opts, listener, false);
    }

    /**
     * Connects this client (made by {@link #create}) to the first endpoint
     * that welcomes it. After a failure the client is closed and holds no
     * thread or socket.
     *
     * @throws IllegalStateException the client is connected already, or another thread is connecting it
     * @throws ClosedException {@link #close()} was called before or meanwhile
     * @throws RefusedException EVATAR refused (BadCredential, Occupied...)
     * @throws IOException no endpoint could be reached
     */
    public void connect() throws IOException, ProtocolException {
        synchronized (lock) {
            if (closing || closedReason != null) {
                throw new ClosedException(closedReason == null ? "closed" : closedReason,
                        "client closed: " + (closedReason == null ? "closed" : closedReason));
            }
            if (connectedOnce) {
                throw new IllegalStateException("already connected (as " + opts.entityId + ")");
            }
            if (connecting) {
                throw new IllegalStateException("already connecting (as " + opts.entityId + ")");
            }
            connecting = true;
        }
        boolean ok = false;
        try {
            Exception last = null;
            for (int i = 0; i < opts.endpoints.size(); i++) {
                try {
                    open(i, false);
                    last = null;
                    break;
                } catch (RefusedException e) {
                    if (!opts.ha || !RETRY_CODES.contains(e.code()) || i == opts.endpoints.size() - 1) {
                        throw e;
                    }
                    last = e;
                } catch (ClosedException e) {
                    throw e;
                } catch (IOException | ProtocolException e) {
                    last = e;
                }
            }
            if (last instanceof ProtocolException pe) {
                throw pe;
            }
            if (last != null) {
                throw (IOException) last;
            }
            synchronized (lock) {
                // Welcomed: the reader runs even when close() came meanwhile,
                // so that close() gets EVATAR's answer to its Bye.
                connectedOnce = true;
                start();
            }
            ok = true;
        } catch (IOException | ProtocolException | RuntimeException e) {
            synchronized (lock) {
                if (transport != null) {
                    try {
                        transport.close();
                    } catch (IOException ignored) {
                        // Closing what failed.
                    }
                    transport = null;
                }
            }
            if (closingNow() && !(e instanceof ClosedException)) {
                throw new ClosedException("closed", "client closed during connect (" + e.getMessage() + ")");
            }
            throw e;
        } finally {
            synchronized (lock) {
                connecting = false;
                if (!ok && closedReason == null) {
                    closedReason = closing ? "closed" : "connect_failed";
                }
                lock.notifyAll();
            }
        }
        if (closingNow()) {
            throw new ClosedException("closed", "client closed during connect");
        }
    }

    /** For tests: a socket is being connected or is in its handshake. */
    boolean isOpening() {
        synchronized (lock) {
            return opening != null;
        }
    }

    private boolean closingNow() {
        synchronized (lock) {
            return closing;
        }
    }

    /** Connects over this program's stdin/stdout, for a program EVATAR started (the port connector). */
    public static EvatarClient connectStdio(Options opts, Listener listener) throws IOException, ProtocolException {
        opts.check();
        EvatarClient c = new EvatarClient(opts, listener, true);
        c.open(0, false);
        synchronized (c.lock) {
            c.connectedOnce = true;
            c.start();
        }
        return c;
    }

    private void start() {
        reader.start();
        if (opts.ha) {
            acker.start();
        }
    }

    // ------------------------------------------------------------------ handshake

    /** Opens endpoint {@code i}, says Hello (or Resume), reads the Welcome. */
    private void open(int i, boolean resume) throws IOException, ProtocolException {
        Transport t;
        if (stdio) {
            t = Transport.stdio();
        } else {
            Socket s = new Socket();
            synchronized (lock) {
                if (closing) {
                    throw new ClosedException("closed", "client closed during connect");
                }
                opening = s;
            }
            try {
                t = opts.tls != null ? Transport.tls(s, opts.endpoints.get(i), opts.connectTimeoutMs, opts.tls)
                        : Transport.tcp(s, opts.endpoints.get(i), opts.connectTimeoutMs);
            } catch (IOException | RuntimeException e) {
                forgetOpening(s);
                s.close();
                throw e;
            }
        }
        try {
            Control hello;
            synchronized (lock) {
                hello = resume && sessionId != null
                        ? new Control.Resume(opts.pairing, opts.role, opts.entityId, opts.credential,
                                sessionId, highestSeq, highestEpoch)
                        : new Control.Hello(opts.pairing, opts.role, opts.entityId, opts.credential,
                                opts.ha ? 2 : 1);
            }
            t.readTimeout(opts.handshakeTimeoutMs);
            boolean helloLost = false;
            try {
                Frames.write(t.out(), hello.toBytes());
            } catch (IOException e) {
                // With TLS 1.3 a server refuses a client certificate after the
                // client's handshake is done: the write may fail, and the
                // reason (the TLS alert) is what a read finds.
                if (!t.isTls()) {
                    throw e;
                }
                helloLost = true;
            }
            byte[] doc;
            try {
                doc = Frames.read(t.in(), Frames.HANDSHAKE_MAX);
            } catch (SocketTimeoutException e) {
                throw new RefusedException("HandshakeTimeout", "no answer to the Hello within "
                        + opts.handshakeTimeoutMs + " ms");
            } catch (SocketException e) {
                if (!helloLost) {
                    throw e;
                }
                // The connection was reset before the alert could be read.
                SSLHandshakeException h = new SSLHandshakeException("the server ended the TLS connection ("
                        + e.getMessage() + "): if this client presents a certificate, the server may not trust it");
                h.initCause(e);
                throw h;
            }
            if (doc == null) {
                throw new EOFException("connection closed during the handshake");
            }
            Object answer = Documents.decode(doc);
            if (answer instanceof Control.Refused r) {
                throw new RefusedException(r.code(), r.message());
            }
            if (!(answer instanceof Control.Welcome w)) {
                throw new ProtocolException("BadHandshake", "expected Welcome, got " + answer.getClass().getSimpleName());
            }
            if (opts.ha && !w.isVersion2()) {
                throw new ProtocolException("BadHandshake", "version 1 Welcome to a version 2 Hello");
            }
            t.readTimeout(opts.ha ? (int) Math.max(3 * w.heartbeat(), 1000) : 0);
            synchronized (lock) {
                if (closing) {
                    throw new ClosedException("closed", "client closed during the handshake");
                }
                opening = null;
                transport = t;
                endpointIndex = i;
                welcome = w;
                maxFrame = w.maxFrame();
                if (opts.ha) {
                    afterWelcome(w);
                }
                sessionId = w.sessionId();
            }
        } catch (IOException | ProtocolException | RuntimeException e) {
            synchronized (lock) {
                opening = null;
            }
            t.close();
            throw e;
        }
    }

    private void forgetOpening(Socket s) {
        synchronized (lock) {
            if (opening == s) {
                opening = null;
            }
        }
    }

    /** Section 11.3 rules 2 and 6 (called holding the lock). */
    private void afterWelcome(Control.Welcome w) throws IOException {
        if (Boolean.TRUE.equals(w.resumed())) {
            if (w.lastAccepted() != null) {
                dropAcceptedUpTo(w.lastAccepted());
            }
        } else {
            highestSeq = 0;
            lastAckedSeq = 0;
            highestEpoch = w.epoch();
            held = false;
            if (description != null && sessionId != null) {
                write(description.toBytes());
                held = true;
            }
        }
        if (!held && (Boolean.TRUE.equals(w.resumed()) || sessionId != null)) {
            for (byte[] s : unacked.values()) {
                write(s);
            }
        }
        highestEpoch = Math.max(highestEpoch, w.epoch());
        lock.notifyAll();
    }

    private void dropAcceptedUpTo(String id) {
        if (!unacked.containsKey(id)) {
            return;
        }
        Iterator<String> it = unacked.keySet().iterator();
        while (it.hasNext()) {
            String k = it.next();
            it.remove();
            acceptedToTell.add(k);
            if (k.equals(id)) {
                break;
            }
        }
        lock.notifyAll();
    }

    /** Tells the listener of the signals accepted since last time (not holding the lock). */
    private void tellAccepted() {
        List<String> ids;
        synchronized (lock) {
            if (acceptedToTell.isEmpty()) {
                return;
            }
            ids = List.copyOf(acceptedToTell);
            acceptedToTell.clear();
        }
        if (listener != null) {
            listener.onAccepted(ids);
        }
    }

    // ------------------------------------------------------------------ API

    /** The Welcome of the current connection. */
    public Control.Welcome welcome() {
        synchronized (lock) {
            return welcome;
        }
    }

    public String entityId() {
        return opts.entityId;
    }

    /** The description last given to {@link #describe}, or null. */
    public Description description() {
        synchronized (lock) {
            return description;
        }
    }

    /** Sends (and remembers, to send again after a new session) this entity's description. */
    public void describe(Description d) throws IOException {
        if (!d.entityId().equals(opts.entityId)) {
            throw new IllegalArgumentException("the description's EntityID " + d.entityId()
                    + " is not this client's " + opts.entityId);
        }
        synchronized (lock) {
            description = d;
            writeOrQueue(d.toBytes(), false);
        }
    }

    /**
     * Asks EVATAR for the pairing's current Binding report (GetBinding,
     * docs/protocol.md section 2, revision 3); it arrives like any report. In
     * version 2 while reconnecting it does nothing: a resumed session is sent
     * the report anyway.
     */
    public void requestBinding() throws IOException {
        synchronized (lock) {
            writeOrQueue(new Control.GetBinding().toBytes(), opts.ha);
        }
    }

    /**
     * Sends a signal; fills in SignalID and Timestamp when the builder has
     * none. Returns the SignalID. In version 2 it waits while the window of
     * unacknowledged signals is full, and a signal sent while disconnected is
     * sent after the reconnect.
     */
    public String send(Signal.Builder b) throws IOException {
        if (b.id() == null) {
            b.id(nextId());
        }
        Signal s = b.build();
        byte[] bytes = s.toBytes();
        synchronized (lock) {
            checkUsable();
            if (opts.ha) {
                long window = welcome == null ? 1024 : welcome.dedupWindow();
                while (unacked.size() >= window - 1 && closedReason == null) {
                    try {
                        lock.wait(100);
                    } catch (InterruptedException e) {
                        Thread.currentThread().interrupt();
                        throw new IOException("interrupted waiting for acknowledgements");
                    }
                }
                unacked.put(s.id(), bytes);
            }
            writeOrQueue(bytes, opts.ha);
        }
        return s.id();
    }

    /** A fresh SignalID, unique for this client. */
    public String nextId() {
        return idPrefix + counter.incrementAndGet();
    }

    /**
     * Sends a request awaiting feedback; the future completes with the
     * {@code Feedback} (the provider's, or EVATAR's Timeout/ProviderGone) or
     * the {@code Error} that answers it.
     */
    public CompletableFuture<Signal> request(Signal.Builder b) throws IOException {
        b.context(Signal.REQUEST);
        if (b.id() == null) {
            b.id(nextId());
        }
        String id = b.id();
        CompletableFuture<Signal> f = new CompletableFuture<>();
        pending.put(id, f);
        f.whenComplete((r, e) -> pending.remove(id));
        try {
            send(b);
        } catch (IOException | RuntimeException e) {
            pending.remove(id);
            throw e;
        }
        return f;
    }

    /** {@link #request(Signal.Builder)} and wait; a {@link TimeoutException} when nothing answers in time. */
    public Signal request(Signal.Builder b, Duration timeout) throws IOException, TimeoutException, InterruptedException {
        CompletableFuture<Signal> f = request(b);
        try {
            return f.get(timeout.toMillis(), TimeUnit.MILLISECONDS);
        } catch (ExecutionException e) {
            throw new IOException("request failed: " + e.getCause().getMessage(), e.getCause());
        } catch (TimeoutException e) {
            f.cancel(false);
            throw e;
        }
    }

    /** The next signal from the inbox (only filled when the client has no listener), or null. */
    public Signal receive(Duration timeout) throws InterruptedException {
        return inbox.poll(timeout.toMillis(), TimeUnit.MILLISECONDS);
    }

    /** The last Binding report received, or null. */
    public Control.Binding binding() {
        synchronized (lock) {
            return binding;
        }
    }

    /** Waits for a Binding report that satisfies {@code test} (the last one counts too). */
    public Control.Binding awaitBinding(Predicate<Control.Binding> test, Duration timeout)
            throws InterruptedException, TimeoutException {
        long end = System.nanoTime() + timeout.toNanos();
        synchronized (lock) {
            while (binding == null || !test.test(binding)) {
                long left = TimeUnit.NANOSECONDS.toMillis(end - System.nanoTime());
                if (left <= 0) {
                    throw new TimeoutException("no such Binding within " + timeout.toMillis() + " ms; last: " + binding);
                }
                if (closedReason != null) {
                    throw new TimeoutException("client closed: " + closedReason);
                }
                lock.wait(left);
            }
            return binding;
        }
    }

    /** Version 2: waits until EVATAR acknowledged every signal sent. */
    public boolean awaitAcks(Duration timeout) throws InterruptedException {
        long end = System.nanoTime() + timeout.toNanos();
        synchronized (lock) {
            while (!unacked.isEmpty()) {
                long left = TimeUnit.NANOSECONDS.toMillis(end - System.nanoTime());
                if (left <= 0 || closedReason != null) {
                    return false;
                }
                lock.wait(left);
            }
            return true;
        }
    }

    /** How many signals wait for EVATAR's acknowledgement (version 2). */
    public int unacknowledged() {
        synchronized (lock) {
            return unacked.size();
        }
    }

    /** How many times a version 2 client reconnected. */
    public int reconnects() {
        synchronized (lock) {
            return reconnects;
        }
    }

    /** Null while open; else why it closed. */
    public String closedReason() {
        synchronized (lock) {
            return closedReason;
        }
    }

    /** Waits until the client is closed; returns the reason or null on timeout. */
    public String awaitClosed(Duration timeout) throws InterruptedException {
        reader.join(timeout.toMillis());
        return closedReason();
    }

    /** Drops the current connection without a Bye (as a crash or a network fault would). For tests. */
    public void dropConnection() throws IOException {
        Transport t;
        synchronized (lock) {
            t = transport;
        }
        if (t != null) {
            t.close();
        }
    }

    /**
     * Closes the client, in any state and any number of times (from any
     * thread; a second call waits like the first). A connect in progress
     * ends with a {@link ClosedException}. Connected, it says Bye and waits
     * for EVATAR's Bye or the end of the connection, at most
     * {@link Options#closeTimeout(Duration)} (5 s by default): EVATAR has
     * then let go of the EntityID, and a new connection with it is not
     * refused {@code EntityExists}. Returns once the client's threads have
     * ended and its socket is closed; pending requests fail, the listener
     * gets {@code onClosed("closed", null)} if the client was connected.
     */
    @Override
    public void close() {
        Transport t;
        Socket o;
        long end = System.nanoTime() + TimeUnit.MILLISECONDS.toNanos(opts.closeTimeoutMs);
        synchronized (lock) {
            boolean first = !closing;
            closing = true;
            t = transport;
            o = opening;
            if (first && t != null && closedReason == null) {
                try {
                    write(new Control.Bye(null).toBytes());
                } catch (IOException e) {
                    // Closed already: nothing to say Bye on.
                }
            }
            lock.notifyAll();
        }
        if (o != null) {
            try {
                o.close();  // ends a connect or a handshake in progress
            } catch (IOException e) {
                // Nothing more to do.
            }
        }
        try {
            synchronized (lock) {
                while (connecting) {
                    long left = TimeUnit.NANOSECONDS.toMillis(end - System.nanoTime());
                    if (left <= 0) {
                        break;
                    }
                    lock.wait(left);
                }
            }
            join(reader, end);
        } catch (InterruptedException e) {
            Thread.currentThread().interrupt();
        }
        if (t != null) {
            try {
                t.close();
            } catch (IOException e) {
                // Nothing more to do.
            }
        }
        try {
            join(reader, System.nanoTime() + TimeUnit.SECONDS.toNanos(1));
        } catch (InterruptedException e) {
            Thread.currentThread().interrupt();
        }
        finish("closed", null);
        try {
            join(acker, System.nanoTime() + TimeUnit.SECONDS.toNanos(1));
        } catch (InterruptedException e) {
            Thread.currentThread().interrupt();
        }
    }

    /** Waits for {@code th} to end until {@code end} (nanoTime); not for the calling thread itself. */
    private static void join(Thread th, long end) throws InterruptedException {
        if (th == Thread.currentThread() || !th.isAlive()) {
            return;
        }
        long left = TimeUnit.NANOSECONDS.toMillis(end - System.nanoTime());
        if (left > 0) {
            th.join(left);
        }
    }

    // ------------------------------------------------------------------ writing

    /** Holding the lock: a ClosedException once closed, an IllegalStateException before connect(). */
    private void checkUsable() throws ClosedException {
        if (closedReason != null) {
            throw new ClosedException(closedReason, "client closed: " + closedReason);
        }
        if (!connectedOnce) {
            throw new IllegalStateException("not connected: call connect() first");
        }
    }

    private void write(byte[] doc) throws IOException {
        if (doc.length > maxFrame) {
            throw new IOException("document of " + doc.length + " bytes over MaxFrame " + maxFrame);
        }
        Frames.write(transport.out(), doc);
    }

    /** Writes now; in version 2, a failed write is left for the reconnect when {@code keep}. */
    private void writeOrQueue(byte[] doc, boolean keep) throws IOException {
        checkUsable();
        if (transport == null || (keep && held)) {
            if (keep) {
                return;
            }
            throw new IOException("not connected");
        }
        try {
            write(doc);
        } catch (IOException e) {
            if (!keep) {
                throw e;
            }
        }
    }

    // ------------------------------------------------------------------ reading

    private void readLoop() {
        while (true) {
            Transport t;
            synchronized (lock) {
                t = transport;
            }
            String lost;
            Throwable cause = null;
            try {
                lost = readFrames(t);
            } catch (RefusedException e) {
                lost = e.code();
                cause = e;
            } catch (IOException | ProtocolException e) {
                lost = e instanceof SocketTimeoutException ? "silent" : "closed";
                cause = e;
            }
            try {
                t.close();
            } catch (IOException e) {
                // Already closed.
            }
            boolean stop;
            synchronized (lock) {
                transport = null;
                stop = closing || !opts.ha || stdio || lost.equals("bye")
                        || (cause instanceof RefusedException && !RETRY_CODES.contains(lost));
            }
            if (stop || !reconnect(lost)) {
                if (!closing || closedReason == null) {
                    finish(closing ? "closed" : lost, cause);
                }
                return;
            }
        }
    }

    /** Reads until the connection ends; returns {@code bye} or {@code closed}. */
    private String readFrames(Transport t) throws IOException, ProtocolException {
        while (true) {
            long max;
            synchronized (lock) {
                max = maxFrame;
            }
            byte[] doc = Frames.read(t.in(), max);
            if (doc == null) {
                return "closed";
            }
            Object d;
            try {
                d = Documents.decode(doc);
            } catch (ProtocolException e) {
                System.err.println("evatar-client " + opts.entityId + ": dropped a frame: " + e.getMessage());
                continue;
            }
            if (d instanceof Signal s) {
                onSignal(s);
            } else if (d instanceof Control.Binding b) {
                synchronized (lock) {
                    binding = b;
                    if (held && b.entities().stream().anyMatch(e -> !e.equals(opts.entityId))) {
                        held = false;
                        for (byte[] queued : unacked.values()) {
                            try {
                                write(queued);
                            } catch (IOException e) {
                                break;  // the connection went: the next session sends them
                            }
                        }
                    }
                    lock.notifyAll();
                }
                if (listener != null) {
                    listener.onBinding(b);
                }
            } else if (d instanceof Control.Ack a) {
                if (a.accepted() != null) {
                    synchronized (lock) {
                        dropAcceptedUpTo(a.accepted());
                    }
                    tellAccepted();
                }
            } else if (d instanceof Control.Refused r) {
                throw new RefusedException(r.code(), r.message());
            } else if (d instanceof Control.Bye) {
                synchronized (lock) {
                    if (!closing && opts.ha) {
                        return "closed";
                    }
                }
                return "bye";
            }
        }
    }

    private void onSignal(Signal s) {
        if (s.sequence() != null) {
            synchronized (lock) {
                if (s.sequence() <= highestSeq
                        || (s.epoch() != null && s.epoch() < highestEpoch)) {
                    return;
                }
                highestSeq = s.sequence();
                if (s.epoch() != null) {
                    highestEpoch = Math.max(highestEpoch, s.epoch());
                }
            }
        }
        String answered = s.inReplyTo();
        if (answered != null && (s.context().equals(Signal.FEEDBACK) || s.context().equals(Signal.ERROR))) {
            CompletableFuture<Signal> f = pending.remove(answered);
            if (f != null) {
                f.complete(s);
                ackSoon();
                return;
            }
        }
        if (listener != null) {
            listener.onSignal(s);
        } else {
            inbox.add(s);
        }
        ackSoon();
    }

    // ------------------------------------------------------------------ version 2

    private void ackSoon() {
        if (!opts.ha) {
            return;
        }
        synchronized (lock) {
            if (highestSeq - lastAckedSeq >= ACK_EVERY) {
                sendAck();
            } else {
                lock.notifyAll();
            }
        }
    }

    private void sendAck() {
        if (transport != null && highestSeq > lastAckedSeq) {
            try {
                write(new Control.Ack(null, highestSeq).toBytes());
                lastAckedSeq = highestSeq;
            } catch (IOException e) {
                // The reader sees the broken connection and reconnects; the Resume carries Received.
            }
        }
    }

    /** Sends Ack Received within a few ms of processing a signal. */
    private void ackLoop() {
        try {
            while (true) {
                synchronized (lock) {
                    if (closedReason != null) {
                        return;
                    }
                    if (highestSeq <= lastAckedSeq || transport == null) {
                        lock.wait(200);
                        continue;
                    }
                }
                Thread.sleep(ACK_DELAY_MS);
                synchronized (lock) {
                    sendAck();
                }
            }
        } catch (InterruptedException e) {
            Thread.currentThread().interrupt();
        }
    }

    /** Section 11.3 rule 5: next endpoint, round the list, growing pause after each round. */
    private boolean reconnect(String why) {
        long start = System.currentTimeMillis();
        int n = opts.endpoints.size();
        int idx;
        synchronized (lock) {
            idx = endpointIndex;
        }
        long pause = opts.backoffMinMs;
        Exception last = null;
        int tried = 0;
        while (System.currentTimeMillis() - start < opts.reconnectLimitMs) {
            synchronized (lock) {
                if (closing) {
                    return false;
                }
            }
            idx = (idx + 1) % n;
            try {
                open(idx, true);
                tellAccepted();
                Control.Welcome w;
                synchronized (lock) {
                    reconnects++;
                    w = welcome;
                }
                if (listener != null) {
                    listener.onReconnected(transportName(), Boolean.TRUE.equals(w.resumed()), w.epoch());
                }
                return true;
            } catch (RefusedException e) {
                last = e;
                if (!RETRY_CODES.contains(e.code())) {
                    finish(e.code(), e);
                    return false;
                }
            } catch (IOException | ProtocolException e) {
                last = e;
            }
            if (++tried % n == 0) {
                try {
                    synchronized (lock) {
                        if (!closing) {
                            lock.wait(pause);  // close() wakes it
                        }
                    }
                } catch (InterruptedException e) {
                    Thread.currentThread().interrupt();
                    return false;
                }
                pause = Math.min(pause * 2, opts.backoffMaxMs);
            }
        }
        finish("gave_up", last);
        return false;
    }

    private String transportName() {
        synchronized (lock) {
            return transport == null ? "?" : transport.describe();
        }
    }

    private void finish(String reason, Throwable cause) {
        synchronized (lock) {
            if (closedReason != null) {
                return;
            }
            closedReason = reason;
            lock.notifyAll();
        }
        ClosedException gone = new ClosedException(reason, "client closed: " + reason);
        if (cause != null) {
            gone.initCause(cause);
        }
        for (CompletableFuture<Signal> f : pending.values()) {
            f.completeExceptionally(gone);
        }
        boolean wasConnected;
        synchronized (lock) {
            wasConnected = connectedOnce;
        }
        if (listener != null && wasConnected) {
            listener.onClosed(reason, cause);
        }
    }
}

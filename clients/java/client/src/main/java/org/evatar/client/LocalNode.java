package org.evatar.client;

import java.io.BufferedReader;
import java.io.IOException;
import java.io.InputStreamReader;
import java.io.OutputStreamWriter;
import java.io.Writer;
import java.nio.charset.StandardCharsets;
import java.nio.file.Files;
import java.nio.file.Path;
import java.util.ArrayList;
import java.util.HashMap;
import java.util.List;
import java.util.Map;
import java.util.concurrent.BlockingQueue;
import java.util.concurrent.LinkedBlockingQueue;
import java.util.concurrent.TimeUnit;

/**
 * An EVATAR node from a checkout of the repository, for development and
 * tests: runs {@code scripts/test-node.sh} (or another script printing
 * {@code EVATAR_PORT=N}) and stops it by closing its stdin. The Erlang code
 * must be compiled ({@code rebar3 compile}; REBAR_BASE_DIR is passed on).
 */
public final class LocalNode implements AutoCloseable {
    private final Process process;
    private final Writer stdin;
    private final BlockingQueue<String> lines = new LinkedBlockingQueue<>();
    private final int port;
    private List<Integer> ports = List.of();
    private Map<String, Integer> named = Map.of();

    private LocalNode(Process p, int port, Writer stdin) {
        this.process = p;
        this.port = port;
        this.stdin = stdin;
    }

    /** The repository root: system property {@code evatar.repo}, env EVATAR_REPO, or found upwards. */
    public static Path repo() {
        String p = System.getProperty("evatar.repo", System.getenv("EVATAR_REPO"));
        if (p != null) {
            return Path.of(p).toAbsolutePath().normalize();
        }
        for (Path d = Path.of("").toAbsolutePath(); d != null; d = d.getParent()) {
            if (Files.exists(d.resolve("scripts/test-node.sh"))) {
                return d;
            }
        }
        throw new IllegalStateException("cannot find the EVATAR repository; set -Devatar.repo");
    }

    /** Starts {@code scripts/test-node.sh} with these PAIRING:AGENT_CREDENTIAL:AVATAR_CREDENTIAL specs. */
    public static LocalNode start(String... pairings) throws IOException {
        return start(repo().resolve("scripts/test-node.sh"), pairings);
    }

    /**
     * Starts {@code scripts/test-node.sh} with TLS listeners too, their
     * certificates in {@code certDir} (made by scripts/gen-bridge-certs.sh):
     * see {@link #tlsPort()} and {@link #mutualTlsPort()}.
     */
    public static LocalNode startTls(Path certDir, String... pairings) throws IOException {
        return start(repo().resolve("scripts/test-node.sh"), Map.of("EVATAR_TLS_DIR", certDir.toString()),
                pairings);
    }

    /**
     * Starts {@code scripts/test-node.sh} whose listener refuses a wrong
     * credential at once, never locks out and has no handshake rate limit
     * ({@code EVATAR_TEST_NO_GUARD}): for tests of many handshakes.
     */
    public static LocalNode startWithoutGuard(String... pairings) throws IOException {
        return start(repo().resolve("scripts/test-node.sh"), Map.of("EVATAR_TEST_NO_GUARD", "1"), pairings);
    }

    /** Starts a node script and waits (at most 120 s) for its EVATAR_PORT line. */
    public static LocalNode start(Path script, String... pairings) throws IOException {
        return start(script, Map.of(), pairings);
    }

    private static LocalNode start(Path script, Map<String, String> env, String... pairings) throws IOException {
        List<String> cmd = new ArrayList<>();
        cmd.add(script.toString());
        cmd.addAll(List.of(pairings));
        ProcessBuilder pb = new ProcessBuilder(cmd).directory(repo().toFile())
                .redirectError(ProcessBuilder.Redirect.INHERIT);
        pb.environment().putAll(env);
        Process p = pb.start();
        Writer w = new OutputStreamWriter(p.getOutputStream(), StandardCharsets.UTF_8);
        BufferedReader r = new BufferedReader(new InputStreamReader(p.getInputStream(), StandardCharsets.UTF_8));
        BlockingQueue<String> q = new LinkedBlockingQueue<>();
        Thread t = new Thread(() -> {
            try {
                for (String l; (l = r.readLine()) != null; ) {
                    q.add(l);
                }
            } catch (IOException e) {
                // The node stopped.
            }
            q.add("\u0000EOF");
        }, "evatar-node-stdout");
        t.setDaemon(true);
        t.start();
        List<Integer> ports = new ArrayList<>();
        Map<String, Integer> named = new HashMap<>();
        try {
            while (true) {
                String l = q.poll(120, TimeUnit.SECONDS);
                if (l == null || l.equals("\u0000EOF")) {
                    p.destroy();
                    throw new IOException("the node did not print EVATAR_PORT (" + script + ")");
                }
                if (l.startsWith("EVATAR_PORTS=")) {
                    for (String x : l.substring(13).strip().split(",")) {
                        ports.add(Integer.parseInt(x));
                    }
                }
                if (l.startsWith("EVATAR_TLS_PORT=") || l.startsWith("EVATAR_MTLS_PORT=")) {
                    String[] kv = l.split("=", 2);
                    named.put(kv[0], Integer.parseInt(kv[1].strip()));
                }
                if (l.startsWith("EVATAR_PORT=")) {
                    LocalNode n = new LocalNode(p, Integer.parseInt(l.substring(12).strip()), w);
                    n.named = Map.copyOf(named);
                    n.ports = ports.isEmpty() ? List.of(n.port) : List.copyOf(ports);
                    q.drainTo(n.lines);
                    Thread fwd = new Thread(() -> {
                        try {
                            while (true) {
                                String x = q.take();
                                n.lines.add(x);
                                if (x.equals("\u0000EOF")) {
                                    return;
                                }
                            }
                        } catch (InterruptedException e) {
                            Thread.currentThread().interrupt();
                        }
                    }, "evatar-node-lines");
                    fwd.setDaemon(true);
                    fwd.start();
                    return n;
                }
            }
        } catch (InterruptedException e) {
            Thread.currentThread().interrupt();
            p.destroy();
            throw new IOException("interrupted", e);
        }
    }

    public int port() {
        return port;
    }

    /** The TLS listener's port (server certificate only), after {@link #startTls}. */
    public int tlsPort() {
        return named.get("EVATAR_TLS_PORT");
    }

    /** The port of the TLS listener that requires client certificates signed by the CA. */
    public int mutualTlsPort() {
        return named.get("EVATAR_MTLS_PORT");
    }

    public String host() {
        return "127.0.0.1";
    }

    /**
     * Sends one command to a node script that takes commands on stdin
     * (scripts/test-node-ctl.sh: {@code port}, {@code entities}, {@code outcome}...)
     * and returns the lines it answered before its final {@code OK}; an
     * {@code ERROR} line is an IOException. Words are joined by spaces.
     */
    public List<String> command(long timeoutSeconds, String... words) throws IOException {
        synchronized (this) {
            stdin.write(String.join(" ", words) + "\n");
            stdin.flush();
            List<String> out = new ArrayList<>();
            try {
                while (true) {
                    String l = lines.poll(timeoutSeconds, TimeUnit.SECONDS);
                    if (l == null) {
                        throw new IOException("no answer to " + words[0] + " within " + timeoutSeconds + " s");
                    }
                    if (l.equals("\u0000EOF")) {
                        throw new IOException("the node stopped");
                    }
                    if (l.startsWith("ERROR")) {
                        throw new IOException("node: " + l);
                    }
                    if (l.equals("OK")) {
                        return out;
                    }
                    out.add(l);
                }
            } catch (InterruptedException e) {
                Thread.currentThread().interrupt();
                throw new IOException("interrupted", e);
            }
        }
    }

    /** The script with commands and a simulated home, a cluster...: scripts/test-node-ctl.sh. */
    public static LocalNode startCtl(String... args) throws IOException {
        return start(repo().resolve("scripts/test-node-ctl.sh"), args);
    }

    /** With {@code --cluster N}: every node's port, in order. */
    public List<Integer> ports() {
        return ports;
    }

    /** Closes the node's stdin (it halts) and waits for it; kills it after 10 s. */
    @Override
    public void close() {
        try {
            stdin.close();
        } catch (IOException e) {
            // Gone already.
        }
        try {
            if (!process.waitFor(10, TimeUnit.SECONDS)) {
                process.destroyForcibly().waitFor(5, TimeUnit.SECONDS);
            }
        } catch (InterruptedException e) {
            Thread.currentThread().interrupt();
            process.destroyForcibly();
        }
    }
}

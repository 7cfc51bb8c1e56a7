package org.evatar.client;

import java.io.BufferedInputStream;
import java.io.BufferedOutputStream;
import java.io.Closeable;
import java.io.FileDescriptor;
import java.io.FileInputStream;
import java.io.FileOutputStream;
import java.io.IOException;
import java.io.InputStream;
import java.io.OutputStream;
import java.net.InetSocketAddress;
import java.net.Socket;
import java.net.SocketException;
import javax.net.ssl.SSLException;
import javax.net.ssl.SSLHandshakeException;
import javax.net.ssl.SSLParameters;
import javax.net.ssl.SSLSocket;

/** Where frames travel: a TCP or TLS connection, or stdin/stdout when EVATAR started the program (a port). */
public interface Transport extends Closeable {
    InputStream in();

    OutputStream out();

    /** Reads block at most {@code ms} (0: for ever); a no-op where the transport cannot time out. */
    void readTimeout(int ms) throws IOException;

    /** A short name for logs and reports. */
    String describe();

    /** Opens a TCP connection to an endpoint. */
    static Transport tcp(InetSocketAddress endpoint, int connectTimeoutMs) throws IOException {
        return tcp(new Socket(), endpoint, connectTimeoutMs);
    }

    /**
     * Opens a TCP connection on {@code s}, a new unconnected socket: closing
     * it from another thread ends the connect at once.
     */
    static Transport tcp(Socket s, InetSocketAddress endpoint, int connectTimeoutMs) throws IOException {
        try {
            s.setTcpNoDelay(true);
            s.connect(endpoint, connectTimeoutMs);
        } catch (IOException e) {
            s.close();
            throw e;
        }
        return of(s, endpoint, false);
    }

    /**
     * Opens a TLS connection to an endpoint and checks the server ({@link Tls});
     * the handshake is done when this returns.
     */
    static Transport tls(InetSocketAddress endpoint, int connectTimeoutMs, Tls tls) throws IOException {
        return tls(new Socket(), endpoint, connectTimeoutMs, tls);
    }

    /** The same on {@code raw}, a new unconnected socket (closing it ends the connect and the TLS handshake). */
    static Transport tls(Socket raw, InetSocketAddress endpoint, int connectTimeoutMs, Tls tls) throws IOException {
        SSLSocket s;
        try {
            raw.setTcpNoDelay(true);
            raw.connect(endpoint, connectTimeoutMs);
            String host = tls.serverName() != null ? tls.serverName() : endpoint.getHostString();
            s = (SSLSocket) tls.context().getSocketFactory().createSocket(raw, host, endpoint.getPort(), true);
        } catch (IOException e) {
            raw.close();
            throw e;
        }
        try {
            SSLParameters p = s.getSSLParameters();
            if (tls.checksHostName()) {
                p.setEndpointIdentificationAlgorithm("HTTPS");
            }
            p.setProtocols(new String[] {"TLSv1.3", "TLSv1.2"});
            s.setSSLParameters(p);
            s.setSoTimeout(connectTimeoutMs);
            s.startHandshake();
            tls.check(s.getSession());
            s.setSoTimeout(0);
        } catch (SSLException e) {
            s.close();
            throw e;
        } catch (SocketException e) {
            // A server that refuses our certificate closes at once; when our
            // last handshake flight is still unread there, its kernel resets
            // the connection and the alert saying why can be lost.
            s.close();
            SSLHandshakeException h = new SSLHandshakeException("the server ended the TLS handshake ("
                    + e.getMessage() + "): if this client presents a certificate, the server may not trust it");
            h.initCause(e);
            throw h;
        } catch (IOException e) {
            s.close();
            throw e;
        }
        return of(s, endpoint, true);
    }

    private static Transport of(Socket s, InetSocketAddress endpoint, boolean tls) throws IOException {
        InputStream in = new BufferedInputStream(s.getInputStream(), 65536);
        OutputStream out = new BufferedOutputStream(s.getOutputStream(), 65536);
        return new Transport() {
            public InputStream in() { return in; }
            public OutputStream out() { return out; }
            public void readTimeout(int ms) throws IOException { s.setSoTimeout(ms); }
            public String describe() { return endpoint.getHostString() + ":" + endpoint.getPort(); }
            public boolean isTls() { return tls; }
            public void close() throws IOException { s.close(); }
        };
    }

    /** Whether this is a TLS connection. */
    default boolean isTls() {
        return false;
    }

    /**
     * This process's stdin and stdout (docs/protocol.md section 9). Nothing else
     * may write to stdout: log to stderr. The streams are taken from the file
     * descriptors, so a stray {@code System.out.println} cannot corrupt frames
     * once {@link #redirectSystemOut()} has been called.
     */
    static Transport stdio() {
        InputStream in = new BufferedInputStream(new FileInputStream(FileDescriptor.in), 65536);
        OutputStream out = new BufferedOutputStream(new FileOutputStream(FileDescriptor.out), 65536);
        return new Transport() {
            public InputStream in() { return in; }
            public OutputStream out() { return out; }
            public void readTimeout(int ms) { }
            public String describe() { return "stdio"; }
            public void close() throws IOException { out.close(); in.close(); }
        };
    }

    /** Points {@code System.out} at stderr, so only frames reach the real stdout. */
    static void redirectSystemOut() {
        System.setOut(System.err);
    }
}

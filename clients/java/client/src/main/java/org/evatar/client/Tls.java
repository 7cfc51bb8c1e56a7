package org.evatar.client;

import java.io.IOException;
import java.io.InputStream;
import java.nio.charset.StandardCharsets;
import java.nio.file.Files;
import java.nio.file.Path;
import java.security.GeneralSecurityException;
import java.security.KeyFactory;
import java.security.KeyStore;
import java.security.MessageDigest;
import java.security.PrivateKey;
import java.security.cert.Certificate;
import java.security.cert.CertificateFactory;
import java.security.cert.X509Certificate;
import java.security.spec.PKCS8EncodedKeySpec;
import java.util.ArrayList;
import java.util.Base64;
import java.util.HexFormat;
import java.util.List;
import java.util.Locale;
import javax.net.ssl.KeyManager;
import javax.net.ssl.KeyManagerFactory;
import javax.net.ssl.SSLContext;
import javax.net.ssl.SSLPeerUnverifiedException;
import javax.net.ssl.SSLSession;
import javax.net.ssl.TrustManager;
import javax.net.ssl.TrustManagerFactory;
import javax.net.ssl.X509TrustManager;

/**
 * How a client connects with TLS (docs/clients.md, "TLS"): the server is
 * checked against a CA file (with its host name), or against a pinned
 * SHA-256 fingerprint of its certificate, or both; with neither, against
 * the JVM's trusted CAs. A client certificate (PEM, with an unencrypted
 * PKCS#8 key as scripts/gen-bridge-certs.sh writes) can be presented.
 * Nothing of the protocol is sent before the server passed every check.
 *
 * <pre>{@code
 * new EvatarClient.Options()...endpoint("evatar.local", 7401)
 *     .tls(Tls.create().caFile(Path.of("certs/ca.pem"))
 *             .clientCertificate(Path.of("certs/client-lamp.pem"), Path.of("certs/client-lamp.key")))
 * }</pre>
 */
public final class Tls {
    private Path caFile;
    private String pinSha256;
    private Path certFile;
    private Path keyFile;
    private String serverName;

    private Tls() {}

    public static Tls create() {
        return new Tls();
    }

    /** The CA (PEM) the server's certificate must chain to. */
    public Tls caFile(Path v) { caFile = v; return this; }

    /** The server certificate's SHA-256 fingerprint, hex (colons and case ignored); alone, it replaces the CA check. */
    public Tls pinSha256(String v) { pinSha256 = v.replace(":", "").toLowerCase(Locale.ROOT); return this; }

    /** A client certificate (PEM) and its private key (PEM, PKCS#8). */
    public Tls clientCertificate(Path cert, Path key) { certFile = cert; keyFile = key; return this; }

    /** The name the server's certificate must carry (default: the host connected to). */
    public Tls serverName(String v) { serverName = v; return this; }

    String serverName() { return serverName; }

    /** Whether the host name is checked (not with a pin alone). */
    boolean checksHostName() { return caFile != null || pinSha256 == null; }

    SSLContext context() throws IOException {
        try {
            SSLContext ctx = SSLContext.getInstance("TLS");
            ctx.init(keyManagers(), trustManagers(), null);
            return ctx;
        } catch (GeneralSecurityException e) {
            throw new IOException("TLS setup: " + e.getMessage(), e);
        }
    }

    /** Throws unless the server's certificate is the pinned one. */
    void check(SSLSession session) throws IOException {
        if (pinSha256 == null) {
            return;
        }
        Certificate[] chain = session.getPeerCertificates();
        String got = fingerprint(chain[0]);
        if (!got.equals(pinSha256)) {
            throw new SSLPeerUnverifiedException("the server's certificate SHA-256 is " + got
                    + ", the pinned one " + pinSha256);
        }
    }

    /** The SHA-256 fingerprint of a certificate, lowercase hex. */
    public static String fingerprint(Certificate c) throws IOException {
        try {
            return HexFormat.of().formatHex(MessageDigest.getInstance("SHA-256").digest(c.getEncoded()));
        } catch (GeneralSecurityException e) {
            throw new IOException(e);
        }
    }

    private TrustManager[] trustManagers() throws GeneralSecurityException, IOException {
        if (caFile == null && pinSha256 != null) {
            // The pin, checked after the handshake, is the trust.
            return new TrustManager[] {new X509TrustManager() {
                public void checkClientTrusted(X509Certificate[] chain, String auth) {}
                public void checkServerTrusted(X509Certificate[] chain, String auth) {}
                public X509Certificate[] getAcceptedIssuers() { return new X509Certificate[0]; }
            }};
        }
        if (caFile == null) {
            return null;
        }
        KeyStore ks = KeyStore.getInstance(KeyStore.getDefaultType());
        ks.load(null, null);
        int i = 0;
        for (Certificate c : certificates(caFile)) {
            ks.setCertificateEntry("ca" + i++, c);
        }
        TrustManagerFactory tmf = TrustManagerFactory.getInstance(TrustManagerFactory.getDefaultAlgorithm());
        tmf.init(ks);
        return tmf.getTrustManagers();
    }

    private KeyManager[] keyManagers() throws GeneralSecurityException, IOException {
        if (certFile == null) {
            return null;
        }
        List<Certificate> chain = certificates(certFile);
        KeyStore ks = KeyStore.getInstance(KeyStore.getDefaultType());
        ks.load(null, null);
        char[] none = new char[0];
        ks.setKeyEntry("client", privateKey(keyFile), none, chain.toArray(Certificate[]::new));
        KeyManagerFactory kmf = KeyManagerFactory.getInstance(KeyManagerFactory.getDefaultAlgorithm());
        kmf.init(ks, none);
        return kmf.getKeyManagers();
    }

    private static List<Certificate> certificates(Path pem) throws GeneralSecurityException, IOException {
        try (InputStream in = Files.newInputStream(pem)) {
            List<Certificate> cs = new ArrayList<>(CertificateFactory.getInstance("X.509").generateCertificates(in));
            if (cs.isEmpty()) {
                throw new IOException(pem + " holds no certificate");
            }
            return cs;
        }
    }

    private static PrivateKey privateKey(Path pem) throws GeneralSecurityException, IOException {
        String text = Files.readString(pem, StandardCharsets.US_ASCII);
        String begin = "-----BEGIN PRIVATE KEY-----";
        int a = text.indexOf(begin);
        int b = text.indexOf("-----END PRIVATE KEY-----");
        if (a < 0 || b < a) {
            throw new IOException(pem + " holds no unencrypted PKCS#8 private key (BEGIN PRIVATE KEY)");
        }
        byte[] der = Base64.getMimeDecoder().decode(text.substring(a + begin.length(), b));
        PKCS8EncodedKeySpec spec = new PKCS8EncodedKeySpec(der);
        for (String alg : List.of("EC", "RSA", "Ed25519")) {
            try {
                return KeyFactory.getInstance(alg).generatePrivate(spec);
            } catch (GeneralSecurityException e) {
                // Try the next algorithm.
            }
        }
        throw new IOException(pem + ": an EC, RSA or Ed25519 key was expected");
    }
}

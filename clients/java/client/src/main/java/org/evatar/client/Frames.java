package org.evatar.client;

import java.io.EOFException;
import java.io.IOException;
import java.io.InputStream;
import java.io.OutputStream;

/** Frames (docs/protocol.md section 1): a 4-byte big-endian length, then one document. */
public final class Frames {
    /** The largest frame before the handshake is done. */
    public static final int HANDSHAKE_MAX = 65536;
    /** The default MaxFrame after the Welcome. */
    public static final int DEFAULT_MAX = 1048576;

    private Frames() {}

    /** One frame's bytes: the length prefix and the document. */
    public static byte[] encode(byte[] document) {
        if (document.length == 0) {
            throw new IllegalArgumentException("an empty document cannot be framed");
        }
        byte[] out = new byte[4 + document.length];
        int n = document.length;
        out[0] = (byte) (n >>> 24);
        out[1] = (byte) (n >>> 16);
        out[2] = (byte) (n >>> 8);
        out[3] = (byte) n;
        System.arraycopy(document, 0, out, 4, n);
        return out;
    }

    public static void write(OutputStream out, byte[] document) throws IOException {
        out.write(encode(document));
        out.flush();
    }

    /**
     * Reads one frame's document. Returns null on a clean end of stream before
     * a frame starts; a length of 0 or over {@code max} is refused from the
     * four length bytes alone; a stream ending inside a frame is an
     * {@link EOFException}.
     */
    public static byte[] read(InputStream in, long max) throws IOException, ProtocolException {
        byte[] len = new byte[4];
        int got = in.readNBytes(len, 0, 4);
        if (got == 0) {
            return null;
        }
        if (got < 4) {
            throw new EOFException("stream ended inside a frame's length");
        }
        long n = ((len[0] & 0xffL) << 24) | ((len[1] & 0xffL) << 16) | ((len[2] & 0xffL) << 8) | (len[3] & 0xffL);
        if (n == 0) {
            throw ProtocolException.malformed("empty_frame", "frame of length 0");
        }
        if (n > max) {
            throw new ProtocolException("FrameTooLarge", "frame of " + n + " bytes, limit " + max);
        }
        byte[] doc = in.readNBytes((int) n);
        if (doc.length < n) {
            throw new EOFException("stream ended inside a frame (" + doc.length + " of " + n + " bytes)");
        }
        return doc;
    }

    /** Decodes one whole frame held in {@code bytes} (for tests and vectors). */
    public static byte[] decode(byte[] bytes, long max) throws IOException, ProtocolException {
        java.io.ByteArrayInputStream in = new java.io.ByteArrayInputStream(bytes);
        byte[] doc = read(in, max);
        if (doc == null) {
            throw new EOFException("no frame");
        }
        if (in.available() > 0) {
            throw ProtocolException.malformed("malformed", in.available() + " bytes after the frame");
        }
        return doc;
    }
}

package org.evatar.client;

/**
 * A document or frame that breaks docs/protocol.md, or a {@code Refused} from
 * EVATAR. {@link #code()} is the protocol's error code ({@code Malformed},
 * {@code FrameTooLarge}, {@code BadCredential}...); {@link #kind()} says more
 * precisely what was wrong with a refused input, in the classes of
 * test/vectors/README.md section 5.4 ({@code doctype_refused},
 * {@code missing_element}...).
 */
public class ProtocolException extends Exception {
    private static final long serialVersionUID = 1L;
    private final String code;
    private final String kind;

    public ProtocolException(String code, String message) {
        this(code, code.equals("FrameTooLarge") ? "frame_too_large" : "malformed", message);
    }

    public ProtocolException(String code, String kind, String message) {
        super(code + " (" + kind + "): " + message);
        this.code = code;
        this.kind = kind;
    }

    public String code() {
        return code;
    }

    public String kind() {
        return kind;
    }

    static ProtocolException malformed(String kind, String message) {
        return new ProtocolException("Malformed", kind, message);
    }
}

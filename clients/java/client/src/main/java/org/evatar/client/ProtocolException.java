package org.evatar.client;

/**
 * A document or frame that breaks docs/protocol.md, or a {@code Refused} from
 * EVATAR. {@link #code()} is the protocol's error code ({@code Malformed},
 * {@code FrameTooLarge}, {@code BadCredential}...).
 */
public class ProtocolException extends Exception {
    private static final long serialVersionUID = 1L;
    private final String code;

    public ProtocolException(String code, String message) {
        super(code + ": " + message);
        this.code = code;
    }

    public String code() {
        return code;
    }
}

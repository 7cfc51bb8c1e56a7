package org.evatar.client;

/** EVATAR refused the connection (a {@code Refused} document) and closed it. */
public class RefusedException extends ProtocolException {
    private static final long serialVersionUID = 1L;
    private final String reason;

    public RefusedException(String code, String message) {
        super(code, message);
        this.reason = message;
    }

    /** The sentence EVATAR gave. */
    public String reason() {
        return reason;
    }
}

package org.evatar.client;

import java.io.IOException;

/**
 * The client is closed: {@link EvatarClient#close()} was called (also while
 * {@link EvatarClient#connect()} was running, which then throws this), or the
 * session ended for good. {@link #reason()} is the client's
 * {@link EvatarClient#closedReason()}.
 */
public class ClosedException extends IOException {
    private static final long serialVersionUID = 1L;
    private final String reason;

    public ClosedException(String reason, String message) {
        super(message);
        this.reason = reason;
    }

    /** {@code closed} after close(), else why the session ended ({@code bye}, {@code gave_up}, a Refused code...). */
    public String reason() {
        return reason;
    }
}

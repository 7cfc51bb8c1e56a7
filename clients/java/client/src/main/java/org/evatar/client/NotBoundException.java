package org.evatar.client;

import java.io.IOException;

/**
 * An emulator cannot address a service: nothing was sent. {@link #why()}
 * tells which case it is.
 */
public class NotBoundException extends IOException {
    private static final long serialVersionUID = 1L;

    /** Why no provider could be named. */
    public enum Why {
        /** The emulator's component does not consume the service in the description this client sent. */
        NOT_CONSUMED,
        /** No Binding report has arrived yet (describe the body and wait with {@code awaitBinding}). */
        NO_BINDING_REPORT,
        /** The last Binding report binds no provider to it (the Avatar is away, or none matches). */
        UNBOUND
    }

    private final Why why;
    private final String component;
    private final String category;
    private final String type;

    public NotBoundException(Why why, String component, String category, String type, String message) {
        super(message);
        this.why = why;
        this.component = component;
        this.category = category;
        this.type = type;
    }

    public Why why() {
        return why;
    }

    public String component() {
        return component;
    }

    public String category() {
        return category;
    }

    public String type() {
        return type;
    }
}

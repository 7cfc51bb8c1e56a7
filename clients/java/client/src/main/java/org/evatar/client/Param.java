package org.evatar.client;

/** One service parameter: {@code <Name>value</Name>} inside ServiceParameters. */
public record Param(String name, String value) {
    public Param {
        if (!Bil.isName(name)) {
            throw new IllegalArgumentException("not a parameter name: " + name);
        }
        if (value == null) {
            throw new IllegalArgumentException("parameter " + name + " has no value");
        }
    }
}

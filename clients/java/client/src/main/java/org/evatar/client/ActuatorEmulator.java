package org.evatar.client;

import java.io.IOException;
import java.time.Duration;
import java.util.List;
import java.util.concurrent.CompletableFuture;
import java.util.concurrent.TimeoutException;

/**
 * A VA's actuator emulator (paper, section 2.2): one component of the VA's
 * description that consumes an Avatar's actuator services. A request goes to
 * the provider component EVATAR bound to it (from the last Binding report).
 */
public class ActuatorEmulator {
    protected final EvatarClient client;
    protected final String component;

    public ActuatorEmulator(EvatarClient client, String component) {
        this.client = client;
        this.component = component;
    }

    public String component() {
        return component;
    }

    /** The provider component bound to this emulator for {@code category}/{@code type}. */
    public String provider(String category, String type) throws IOException {
        Control.Binding b = client.binding();
        if (b == null) {
            throw new IOException("not bound yet: no Binding report received");
        }
        List<Control.Bound> rows = b.consumedBy(client.entityId(), component).stream()
                .filter(r -> keyword(r.category()).equals(keyword(category))
                        && keyword(r.type()).equals(keyword(type))).toList();
        if (rows.isEmpty()) {
            throw new IOException(component + " is not bound for " + category + "/" + type);
        }
        return rows.get(0).providerComponent();
    }

    /** A keyword as binding compares them (docs/bil.md section 4): case-folded letters and digits. */
    public static String keyword(String s) {
        StringBuilder sb = new StringBuilder();
        java.text.Normalizer.normalize(s, java.text.Normalizer.Form.NFC).codePoints()
                .filter(Character::isLetterOrDigit)
                .forEach(c -> sb.appendCodePoint(Character.toLowerCase(Character.toUpperCase(c))));
        return sb.toString();
    }

    /** Sends a request awaiting feedback for an ACTUATOR service. */
    public CompletableFuture<Signal> request(String type, List<Param> params) throws IOException {
        return request("ACTUATOR", type, params);
    }

    public CompletableFuture<Signal> request(String category, String type, List<Param> params) throws IOException {
        return client.request(Signal.builder().sender(component).receiver(provider(category, type))
                .service(category, type).params(params));
    }

    /** Requests and waits for the answer. */
    public Signal call(String type, List<Param> params, Duration timeout)
            throws IOException, TimeoutException, InterruptedException {
        return client.request(Signal.builder().sender(component).receiver(provider("ACTUATOR", type))
                .service("ACTUATOR", type).params(params), timeout);
    }
}

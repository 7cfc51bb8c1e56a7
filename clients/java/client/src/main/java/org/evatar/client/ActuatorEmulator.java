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

    /**
     * The provider component bound to this emulator for {@code category}/{@code type}.
     *
     * @throws NotBoundException nothing to address, nothing sent: the component does not consume the
     *     service in the description this client sent ({@code NOT_CONSUMED}), no Binding report
     *     came yet ({@code NO_BINDING_REPORT}), or the last one binds no provider ({@code UNBOUND})
     */
    public String provider(String category, String type) throws NotBoundException {
        Description d = client.description();
        if (d != null && d.component(component).map(c -> c.consumes().stream()
                .noneMatch(e -> keyword(e.category()).equals(keyword(category))
                        && keyword(e.type()).equals(keyword(type)))).orElse(true)) {
            throw new NotBoundException(NotBoundException.Why.NOT_CONSUMED, component, category, type,
                    component + " does not consume " + category + "/" + type + " in the description of "
                    + client.entityId());
        }
        Control.Binding b = client.binding();
        if (b == null) {
            throw new NotBoundException(NotBoundException.Why.NO_BINDING_REPORT, component, category, type,
                    "not bound yet: no Binding report received");
        }
        List<Control.Bound> rows = b.consumedBy(client.entityId(), component).stream()
                .filter(r -> keyword(r.category()).equals(keyword(category))
                        && keyword(r.type()).equals(keyword(type))).toList();
        if (rows.isEmpty()) {
            throw new NotBoundException(NotBoundException.Why.UNBOUND, component, category, type,
                    component + " is not bound for " + category + "/" + type);
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

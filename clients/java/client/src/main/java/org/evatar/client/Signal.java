package org.evatar.client;

import java.nio.charset.StandardCharsets;
import java.util.ArrayList;
import java.util.Iterator;
import java.util.List;
import java.util.Optional;
import org.w3c.dom.Element;

/**
 * A BIL signal (an {@code Envelope}, docs/bil.md section 3). Immutable; build
 * one with {@link #builder()}, change one with {@link #toBuilder()}.
 * {@code origin} is {@code "EVATAR"} on a signal EVATAR made itself (its
 * Timeout and ProviderGone feedback, its errors) and {@code null} on an
 * entity's: the header's {@code Origin}, which EVATAR refuses from entities.
 */
public record Signal(String id, String context, String sender, String receiver,
                     String inReplyTo, long timestamp, Long sequence, Long epoch,
                     String category, String type, List<Param> parameters, String origin) {

    /** The value of {@code Origin} on EVATAR's own signals. */
    public static final String ORIGIN_EVATAR = "EVATAR";

    public static final String REQUEST = "RequestAwaitingFeedback";
    public static final String REQUEST_NO_FEEDBACK = "Request";
    public static final String FEEDBACK = "Feedback";
    public static final String PROGRESS = "Progress";
    public static final String SENSOR_DATA = "SensorData";
    public static final String EVENT = "Event";
    public static final String ERROR = "Error";

    /** The contexts on the wire (docs/bil.md section 3). */
    public static final java.util.Set<String> CONTEXTS = java.util.Set.of(REQUEST, REQUEST_NO_FEEDBACK,
            FEEDBACK, PROGRESS, SENSOR_DATA, EVENT, ERROR);

    public Signal {
        require(id, "SignalID");
        require(context, "Context");
        require(sender, "Sender");
        require(receiver, "Receiver");
        require(category, "ServiceCategory");
        require(type, "ServiceType");
        if (timestamp < 0) {
            throw new IllegalArgumentException("negative Timestamp");
        }
        parameters = List.copyOf(parameters == null ? List.of() : parameters);
        if (origin != null && !ORIGIN_EVATAR.equals(origin)) {
            throw new IllegalArgumentException("Origin can only be EVATAR, not " + origin);
        }
    }

    /** A signal without {@code Origin}: an entity's. */
    public Signal(String id, String context, String sender, String receiver, String inReplyTo,
                  long timestamp, Long sequence, Long epoch, String category, String type,
                  List<Param> parameters) {
        this(id, context, sender, receiver, inReplyTo, timestamp, sequence, epoch, category, type,
                parameters, null);
    }

    /** True for a signal EVATAR made itself ({@code Origin} {@code EVATAR}), whatever its Sender says. */
    public boolean isFromEvatar() {
        return ORIGIN_EVATAR.equals(origin);
    }

    private static void require(String v, String what) {
        if (v == null || v.isEmpty()) {
            throw new IllegalArgumentException(what + " must not be empty");
        }
    }

    /** The first parameter named {@code name}. */
    public Optional<String> param(String name) {
        return parameters.stream().filter(p -> p.name().equals(name)).map(Param::value).findFirst();
    }

    /** EVATAR's own answer when the feedback deadline passed (docs/protocol.md section 4). */
    public boolean isTimeout() {
        return FEEDBACK.equals(context) && isFromEvatar() && "EVATAR".equals(sender)
                && "EVATAR".equals(category) && "Timeout".equals(type);
    }

    /** A Feedback or Progress from the provider, not an error or EVATAR's timeout/ProviderGone. */
    public boolean isSuccess() {
        return (FEEDBACK.equals(context) || PROGRESS.equals(context)) && !"EVATAR".equals(category);
    }

    public boolean isError() {
        return ERROR.equals(context);
    }

    /** The signal as a document (with an XML declaration, like EVATAR writes them). */
    public String encode() {
        StringBuilder sb = new StringBuilder(512);
        sb.append("<?xml version=\"1.0\" encoding=\"UTF-8\"?>");
        sb.append("<bil:Envelope xmlns:bil=\"").append(Bil.NS).append("\"><bil:Header>");
        Bil.field(sb, "SignalID", id);
        Bil.field(sb, "Context", context);
        Bil.field(sb, "Sender", sender);
        Bil.field(sb, "Receiver", receiver);
        if (inReplyTo != null) {
            Bil.field(sb, "InReplyTo", inReplyTo);
        }
        Bil.field(sb, "Timestamp", Long.toString(timestamp));
        if (sequence != null) {
            Bil.field(sb, "Sequence", Long.toString(sequence));
        }
        if (epoch != null) {
            Bil.field(sb, "Epoch", Long.toString(epoch));
        }
        if (origin != null) {
            Bil.field(sb, "Origin", origin);
        }
        sb.append("</bil:Header><bil:Body>");
        Bil.field(sb, "ServiceCategory", category);
        Bil.field(sb, "ServiceType", type);
        if (parameters.isEmpty()) {
            sb.append("<ServiceParameters/>");
        } else {
            sb.append("<ServiceParameters>");
            for (Param p : parameters) {
                Bil.field(sb, p.name(), p.value());
            }
            sb.append("</ServiceParameters>");
        }
        sb.append("</bil:Body></bil:Envelope>");
        return sb.toString();
    }

    public byte[] toBytes() {
        return encode().getBytes(StandardCharsets.UTF_8);
    }

    /** Decodes a parsed {@code bil:Envelope}. */
    public static Signal decode(Element root) throws ProtocolException {
        if (!Bil.isBil(root, "Envelope")) {
            throw ProtocolException.malformed("wrong_root", "not an Envelope: " + root.getLocalName());
        }
        List<Element> parts = Bil.children(root);
        if (parts.size() != 2 || !Bil.isBil(parts.get(0), "Header") || !Bil.isBil(parts.get(1), "Body")) {
            throw ProtocolException.malformed(parts.stream().anyMatch(x -> x.getNamespaceURI() == null)
                    ? "wrong_namespace" : "missing_element", "Envelope must hold bil:Header then bil:Body");
        }
        Builder b = builder();
        Iterator<Element> h = Bil.children(parts.get(0)).iterator();
        Element e = next(h);
        b.id = expect(e, "SignalID");
        b.context = expect(next(h), "Context");
        if (!CONTEXTS.contains(b.context)) {
            throw ProtocolException.malformed("bad_value", "unknown Context " + b.context);
        }
        b.sender = expect(next(h), "Sender");
        b.receiver = expect(next(h), "Receiver");
        e = next(h);
        if (e != null && Bil.isField(e, "InReplyTo")) {
            b.inReplyTo = nonEmpty(e);
            e = next(h);
        }
        if (e == null || !Bil.isField(e, "Timestamp")) {
            throw Bil.missing("Header", "Timestamp", e);
        }
        b.timestamp = Bil.number(e);
        e = next(h);
        if (e != null && Bil.isField(e, "Sequence")) {
            b.sequence = Bil.number(e);
            e = next(h);
        }
        if (e != null && Bil.isField(e, "Epoch")) {
            b.epoch = Bil.number(e);
            e = next(h);
        }
        if (e != null && Bil.isField(e, "Origin")) {
            b.origin = Bil.text(e);
            if (!ORIGIN_EVATAR.equals(b.origin)) {
                throw ProtocolException.malformed("bad_value", "Origin must be EVATAR, not " + b.origin);
            }
            e = next(h);
        }
        if (e != null) {
            throw ProtocolException.malformed("malformed", "Header: unexpected element " + e.getLocalName());
        }
        Iterator<Element> body = Bil.children(parts.get(1)).iterator();
        b.category = expect(next(body), "ServiceCategory");
        b.type = expect(next(body), "ServiceType");
        e = next(body);
        if (e != null && Bil.isField(e, "ServiceParameters")) {
            java.util.Set<String> seen = new java.util.HashSet<>();
            for (Element p : Bil.children(e)) {
                if (p.getNamespaceURI() != null) {
                    throw ProtocolException.malformed("wrong_namespace", "parameter in a namespace: " + p.getLocalName());
                }
                if (!seen.add(p.getLocalName())) {
                    throw ProtocolException.malformed("duplicate_element", "parameter " + p.getLocalName() + " twice");
                }
                b.parameters.add(new Param(p.getLocalName(), Bil.text(p)));
            }
            e = next(body);
        }
        if (e != null) {
            throw ProtocolException.malformed("malformed", "Body: unexpected element " + e.getLocalName());
        }
        try {
            return b.build();
        } catch (IllegalArgumentException ex) {
            throw ProtocolException.malformed("bad_value", ex.getMessage());
        }
    }

    private static Element next(Iterator<Element> it) {
        return it.hasNext() ? it.next() : null;
    }

    private static String expect(Element e, String name) throws ProtocolException {
        if (e == null || !Bil.isField(e, name)) {
            throw Bil.missing("Envelope", name, e);
        }
        return nonEmpty(e);
    }

    private static String nonEmpty(Element e) throws ProtocolException {
        String t = Bil.text(e);
        if (t.isEmpty()) {
            throw ProtocolException.malformed("bad_value", e.getLocalName() + " is empty");
        }
        return t;
    }

    public static Builder builder() {
        return new Builder();
    }

    public Builder toBuilder() {
        Builder b = new Builder();
        b.id = id;
        b.context = context;
        b.sender = sender;
        b.receiver = receiver;
        b.inReplyTo = inReplyTo;
        b.timestamp = timestamp;
        b.sequence = sequence;
        b.epoch = epoch;
        b.origin = origin;
        b.category = category;
        b.type = type;
        b.parameters = new ArrayList<>(parameters);
        return b;
    }

    /** Builds signals; {@code id} and {@code timestamp} are filled in by the client when left out. */
    public static final class Builder {
        private String id;
        private String context = REQUEST;
        private String sender;
        private String receiver;
        private String inReplyTo;
        private long timestamp = -1;
        private Long sequence;
        private Long epoch;
        private String origin;
        private String category;
        private String type;
        private List<Param> parameters = new ArrayList<>();

        public Builder id(String v) { id = v; return this; }
        public Builder context(String v) { context = v; return this; }
        public Builder sender(String v) { sender = v; return this; }
        public Builder receiver(String v) { receiver = v; return this; }
        public Builder inReplyTo(String v) { inReplyTo = v; return this; }
        public Builder timestamp(long v) { timestamp = v; return this; }
        public Builder sequence(Long v) { sequence = v; return this; }
        public Builder epoch(Long v) { epoch = v; return this; }
        public Builder origin(String v) { origin = v; return this; }
        public Builder service(String cat, String typ) { category = cat; type = typ; return this; }
        public Builder param(String name, String value) { parameters.add(new Param(name, value)); return this; }
        public Builder params(List<Param> ps) { parameters.addAll(ps); return this; }

        String id() { return id; }

        public Signal build() {
            return new Signal(id, context, sender, receiver, inReplyTo,
                    timestamp < 0 ? System.currentTimeMillis() : timestamp,
                    sequence, epoch, category, type, parameters, origin);
        }
    }
}

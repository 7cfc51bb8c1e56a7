package org.evatar.client;

import java.nio.charset.StandardCharsets;
import java.util.ArrayList;
import java.util.List;
import org.w3c.dom.Element;

/**
 * The control documents of docs/protocol.md section 2: {@code Hello},
 * {@code Resume}, {@code Welcome}, {@code Ack}, {@code Refused},
 * {@code Binding}, {@code GetBinding}, {@code Bye}. Fields are read in order; elements after the
 * last known field are ignored (later versions may append fields).
 */
public sealed interface Control {

    /** The document, without an XML declaration (as EVATAR writes control documents). */
    String encode();

    default byte[] toBytes() {
        return encode().getBytes(StandardCharsets.UTF_8);
    }

    record Hello(String pairing, String role, String entityId, String credential, int protocolVersion)
            implements Control {
        @Override
        public String encode() {
            StringBuilder sb = open("Hello");
            hello(sb, pairing, role, entityId, credential, protocolVersion);
            return close(sb, "Hello");
        }
    }

    record Resume(String pairing, String role, String entityId, String credential,
                  String sessionId, long received, long epoch) implements Control {
        @Override
        public String encode() {
            StringBuilder sb = open("Resume");
            hello(sb, pairing, role, entityId, credential, 2);
            Bil.field(sb, "SessionID", sessionId);
            Bil.field(sb, "Received", Long.toString(received));
            Bil.field(sb, "Epoch", Long.toString(epoch));
            return close(sb, "Resume");
        }
    }

    /** A Welcome; the version 2 fields are null in a version 1 Welcome. */
    record Welcome(String pairing, String entityId, String sessionId, long joinTimeout, long maxFrame,
                   Long epoch, Boolean resumed, String lastAccepted, Long dedupWindow, Long heartbeat)
            implements Control {
        public boolean isVersion2() {
            return epoch != null;
        }

        @Override
        public String encode() {
            StringBuilder sb = open("Welcome");
            Bil.field(sb, "Pairing", pairing);
            Bil.field(sb, "EntityID", entityId);
            Bil.field(sb, "SessionID", sessionId);
            Bil.field(sb, "JoinTimeout", Long.toString(joinTimeout));
            Bil.field(sb, "MaxFrame", Long.toString(maxFrame));
            if (epoch != null) {
                Bil.field(sb, "Epoch", Long.toString(epoch));
                Bil.field(sb, "Resumed", Boolean.toString(resumed));
                Bil.field(sb, "LastAccepted", lastAccepted == null ? "" : lastAccepted);
                Bil.field(sb, "DedupWindow", Long.toString(dedupWindow));
                Bil.field(sb, "Heartbeat", Long.toString(heartbeat));
            }
            return close(sb, "Welcome");
        }
    }

    /** An Ack: {@code accepted} from EVATAR, {@code received} from a client; both null: a heartbeat. */
    record Ack(String accepted, Long received) implements Control {
        @Override
        public String encode() {
            StringBuilder sb = open("Ack");
            if (accepted != null) {
                Bil.field(sb, "Accepted", accepted);
            }
            if (received != null) {
                Bil.field(sb, "Received", Long.toString(received));
            }
            return close(sb, "Ack");
        }
    }

    record Refused(String code, String message) implements Control {
        @Override
        public String encode() {
            StringBuilder sb = open("Refused");
            Bil.field(sb, "Code", code);
            Bil.field(sb, "Message", message);
            return close(sb, "Refused");
        }
    }

    record Bye(String reason) implements Control {
        @Override
        public String encode() {
            StringBuilder sb = open("Bye");
            if (reason != null && !reason.isEmpty()) {
                Bil.field(sb, "Reason", reason);
            }
            return close(sb, "Bye");
        }
    }

    /**
     * Asks EVATAR for the pairing's current Binding report, sent to this entity only
     * (docs/protocol.md section 2, revision 3). No fields.
     */
    record GetBinding() implements Control {
        @Override
        public String encode() {
            return close(open("GetBinding"), "GetBinding");
        }
    }

    /** One bound relationship of a Binding report. */
    record Bound(String consumerEntity, String consumerComponent, String providerEntity,
                 String providerComponent, String category, String type, long score, long candidates) {}

    /** One consumer service left without a provider. */
    record Unbound(String consumerEntity, String consumerComponent, String category, String type,
                   String reason) {}

    /** The Body Mapping Registry after a (re)binding. */
    record Binding(List<String> entities, List<Bound> bound, List<Unbound> unbound) implements Control {
        public Binding {
            entities = List.copyOf(entities);
            bound = List.copyOf(bound);
            unbound = List.copyOf(unbound);
        }

        /** The relationships in which {@code component} of {@code entity} is the consumer. */
        public List<Bound> consumedBy(String entity, String component) {
            return bound.stream().filter(b -> b.consumerEntity.equals(entity)
                    && b.consumerComponent.equals(component)).toList();
        }

        @Override
        public String encode() {
            StringBuilder sb = open("Binding");
            sb.append("<Entities>");
            for (String e : entities) {
                Bil.field(sb, "EntityID", e);
            }
            sb.append("</Entities>");
            for (Bound b : bound) {
                sb.append("<Bound>");
                Bil.field(sb, "ConsumerEntity", b.consumerEntity);
                Bil.field(sb, "ConsumerComponent", b.consumerComponent);
                Bil.field(sb, "ProviderEntity", b.providerEntity);
                Bil.field(sb, "ProviderComponent", b.providerComponent);
                Bil.field(sb, "ServiceCategory", b.category);
                Bil.field(sb, "ServiceType", b.type);
                Bil.field(sb, "Score", Long.toString(b.score));
                Bil.field(sb, "Candidates", Long.toString(b.candidates));
                sb.append("</Bound>");
            }
            for (Unbound u : unbound) {
                sb.append("<Unbound>");
                Bil.field(sb, "ConsumerEntity", u.consumerEntity);
                Bil.field(sb, "ConsumerComponent", u.consumerComponent);
                Bil.field(sb, "ServiceCategory", u.category);
                Bil.field(sb, "ServiceType", u.type);
                Bil.field(sb, "Reason", u.reason);
                sb.append("</Unbound>");
            }
            return close(sb, "Binding");
        }
    }

    // ------------------------------------------------------------------ encoding

    private static StringBuilder open(String root) {
        return new StringBuilder(256).append("<bil:").append(root)
                .append(" xmlns:bil=\"").append(Bil.NS).append("\">");
    }

    private static String close(StringBuilder sb, String root) {
        return sb.append("</bil:").append(root).append('>').toString();
    }

    private static void hello(StringBuilder sb, String pairing, String role, String entityId,
                              String credential, int version) {
        Bil.field(sb, "Pairing", pairing);
        Bil.field(sb, "Role", role);
        Bil.field(sb, "EntityID", entityId);
        Bil.field(sb, "Credential", credential);
        Bil.field(sb, "ProtocolVersion", Integer.toString(version));
    }

    // ------------------------------------------------------------------ decoding

    /** The control document names. */
    static boolean isControl(String localName) {
        return switch (localName) {
            case "Hello", "Resume", "Welcome", "Ack", "Refused", "Binding", "GetBinding", "Bye" -> true;
            default -> false;
        };
    }

    /** Decodes a parsed control document. */
    static Control decode(Element root) throws ProtocolException {
        Fields f = new Fields(root);
        return switch (root.getLocalName()) {
            case "Hello" -> new Hello(f.text("Pairing"), role(f.text("Role")), f.text("EntityID"),
                    f.text("Credential"), version(f.number("ProtocolVersion")));
            case "Resume" -> resume(f);
            case "Welcome" -> welcome(f);
            case "Ack" -> new Ack(f.optText("Accepted"), f.optNumber("Received"));
            case "Refused" -> new Refused(f.text("Code"), f.text("Message"));
            case "Bye" -> new Bye(f.optText("Reason"));
            case "GetBinding" -> new GetBinding();
            case "Binding" -> binding(root);
            default -> throw ProtocolException.malformed("wrong_root", "unknown document " + root.getLocalName());
        };
    }

    private static Welcome welcome(Fields f) throws ProtocolException {
        String pairing = f.text("Pairing");
        String entity = f.text("EntityID");
        String session = f.text("SessionID");
        long join = f.number("JoinTimeout");
        long max = f.number("MaxFrame");
        if (!f.at("Epoch")) {
            return new Welcome(pairing, entity, session, join, max, null, null, null, null, null);
        }
        long epoch = f.number("Epoch");
        String resumed = f.text("Resumed");
        if (!resumed.equals("true") && !resumed.equals("false")) {
            throw ProtocolException.malformed("bad_value", "Resumed must be true or false: " + resumed);
        }
        String last = f.text("LastAccepted");
        return new Welcome(pairing, entity, session, join, max, epoch, resumed.equals("true"),
                last.isEmpty() ? null : last, f.number("DedupWindow"), f.number("Heartbeat"));
    }

    private static Binding binding(Element root) throws ProtocolException {
        List<Element> cs = Bil.children(root);
        if (cs.isEmpty() || !Bil.isField(cs.get(0), "Entities")) {
            throw Bil.missing("Binding", "Entities", cs.isEmpty() ? null : cs.get(0));
        }
        List<String> ids = new ArrayList<>();
        for (Element e : Bil.children(cs.get(0))) {
            if (!Bil.isField(e, "EntityID")) {
                throw Bil.missing("Binding/Entities", "EntityID", e);
            }
            ids.add(Bil.text(e));
        }
        List<Bound> bound = new ArrayList<>();
        List<Unbound> unbound = new ArrayList<>();
        for (Element row : cs.subList(1, cs.size())) {
            Fields f = new Fields(row);
            if (Bil.isField(row, "Bound") && unbound.isEmpty()) {
                bound.add(new Bound(f.text("ConsumerEntity"), f.text("ConsumerComponent"),
                        f.text("ProviderEntity"), f.text("ProviderComponent"), f.text("ServiceCategory"),
                        f.text("ServiceType"), f.number("Score"), f.number("Candidates")));
            } else if (Bil.isField(row, "Unbound")) {
                unbound.add(new Unbound(f.text("ConsumerEntity"), f.text("ConsumerComponent"),
                        f.text("ServiceCategory"), f.text("ServiceType"), f.text("Reason")));
            } else {
                break;
            }
        }
        return new Binding(ids, bound, unbound);
    }

    private static String role(String r) throws ProtocolException {
        if (!r.equals("agent") && !r.equals("avatar")) {
            throw ProtocolException.malformed("bad_value", "Role must be agent or avatar: " + r);
        }
        return r;
    }

    private static int version(long v) throws ProtocolException {
        if (v > Integer.MAX_VALUE) {
            throw new ProtocolException("BadHandshake", "bad_value", "ProtocolVersion " + v);
        }
        return (int) v;
    }

    private static Resume resume(Fields f) throws ProtocolException {
        String pairing = f.text("Pairing");
        String role = role(f.text("Role"));
        String entity = f.text("EntityID");
        String credential = f.text("Credential");
        if (f.number("ProtocolVersion") != 2) {
            throw new ProtocolException("BadHandshake", "a Resume must say ProtocolVersion 2");
        }
        return new Resume(pairing, role, entity, credential, f.text("SessionID"), f.number("Received"),
                f.number("Epoch"));
    }

    /** Reads the fields of a control document in order. */
    final class Fields {
        private final List<Element> elements;
        private final String where;
        private int next;

        Fields(Element parent) {
            this.elements = Bil.children(parent);
            this.where = parent.getLocalName();
        }

        boolean at(String name) {
            return next < elements.size() && Bil.isField(elements.get(next), name);
        }

        String text(String name) throws ProtocolException {
            if (!at(name)) {
                throw Bil.missing(where, name, next < elements.size() ? elements.get(next) : null);
            }
            return Bil.text(elements.get(next++));
        }

        long number(String name) throws ProtocolException {
            if (!at(name)) {
                text(name);
            }
            return Bil.number(elements.get(next++));
        }

        String optText(String name) throws ProtocolException {
            return at(name) ? text(name) : null;
        }

        Long optNumber(String name) throws ProtocolException {
            return at(name) ? number(name) : null;
        }
    }
}

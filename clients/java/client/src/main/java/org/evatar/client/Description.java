package org.evatar.client;

import java.nio.charset.StandardCharsets;
import java.util.ArrayList;
import java.util.Iterator;
import java.util.List;
import java.util.Optional;
import org.w3c.dom.Element;

/**
 * A BIL description (docs/bil.md section 2): who the entity is and what its
 * components provide ({@code Service}) and consume ({@code Consumes}).
 */
public record Description(String entityId, String apiName, String entityType, String context,
                          List<Component> components) {

    public Description {
        if (entityId == null || entityId.isEmpty()) {
            throw new IllegalArgumentException("EntityID must not be empty");
        }
        if (!entityType.equals("Agent") && !entityType.equals("Avatar")) {
            throw new IllegalArgumentException("EntityType must be Agent or Avatar: " + entityType);
        }
        components = List.copyOf(components);
    }

    /** A service offered or consumed: category, type and parameters. */
    public record Service(String category, String type, List<Param> parameters) {
        public Service {
            parameters = List.copyOf(parameters);
        }

        public Service(String category, String type) {
            this(category, type, List.of());
        }

        public Optional<String> param(String name) {
            return parameters.stream().filter(p -> p.name().equals(name)).map(Param::value).findFirst();
        }
    }

    /** A component: an emulator object of a VA, or a sensor or actuator of an Avatar. */
    public record Component(String id, List<Service> services, List<Service> consumes) {
        public Component {
            if (id == null || id.isEmpty()) {
                throw new IllegalArgumentException("ComponentID must not be empty");
            }
            if (services.isEmpty()) {
                throw new IllegalArgumentException("component " + id + " provides no Service");
            }
            services = List.copyOf(services);
            consumes = List.copyOf(consumes);
        }
    }

    /** A description of a VA with these components. */
    public static Description agent(String entityId, List<Component> components) {
        return new Description(entityId, "EVATAR JAVA CLIENT", "Agent", "EmulatorDescription", components);
    }

    /** A description of an Avatar with these components. */
    public static Description avatar(String entityId, List<Component> components) {
        return new Description(entityId, "EVATAR JAVA CLIENT", "Avatar", "DeviceDescription", components);
    }

    /** The same description under another EntityID. */
    public Description withEntityId(String id) {
        return new Description(id, apiName, entityType, context, components);
    }

    public Optional<Component> component(String id) {
        return components.stream().filter(c -> c.id().equals(id)).findFirst();
    }

    /** The description as EVATAR writes them: two spaces per level, one element a line. */
    public String encode() {
        StringBuilder sb = new StringBuilder(1024);
        sb.append("<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n");
        sb.append("<bil:description xmlns:bil=\"").append(Bil.NS).append("\">\n");
        sb.append("  <bil:context>\n");
        line(sb, 4, "EntityID", entityId);
        line(sb, 4, "APIName", apiName);
        line(sb, 4, "EntityType", entityType);
        line(sb, 4, "Context", context);
        sb.append("  </bil:context>\n");
        if (components.isEmpty()) {
            sb.append("  <bil:types/>\n");
        } else {
            sb.append("  <bil:types>\n");
            for (Component c : components) {
                sb.append("    <bil:Component>\n");
                line(sb, 6, "ComponentID", c.id());
                for (Service s : c.services()) {
                    entry(sb, "Service", s);
                }
                for (Service s : c.consumes()) {
                    entry(sb, "Consumes", s);
                }
                sb.append("    </bil:Component>\n");
            }
            sb.append("  </bil:types>\n");
        }
        sb.append("</bil:description>\n");
        return sb.toString();
    }

    private static void line(StringBuilder sb, int indent, String name, String text) {
        sb.append(" ".repeat(indent));
        Bil.field(sb, name, text);
        sb.append('\n');
    }

    public byte[] toBytes() {
        return encode().getBytes(StandardCharsets.UTF_8);
    }

    private static void entry(StringBuilder sb, String tag, Service s) {
        sb.append("      <").append(tag).append(">\n");
        line(sb, 8, "ServiceCategory", s.category());
        line(sb, 8, "ServiceType", s.type());
        if (s.parameters().isEmpty()) {
            sb.append("        <ServiceParameters/>\n");
        } else {
            sb.append("        <ServiceParameters>\n");
            for (Param p : s.parameters()) {
                line(sb, 10, p.name(), p.value());
            }
            sb.append("        </ServiceParameters>\n");
        }
        sb.append("      </").append(tag).append(">\n");
    }

    /** Parses a description document (for example one of apps/bil/priv/examples). */
    public static Description parse(byte[] xml) throws ProtocolException {
        Element root = Bil.parse(xml);
        if (!Bil.isBil(root, "description")) {
            throw ProtocolException.malformed("wrong_root", "not a bil:description: " + root.getLocalName());
        }
        return decode(root);
    }

    static Documents.DescriptionDoc decodeHead(Element root, String xml) throws ProtocolException {
        Description d = decode(root);
        return new Documents.DescriptionDoc(d.entityId(), d.entityType(), xml);
    }

    static Description decode(Element root) throws ProtocolException {
        List<Element> parts = Bil.children(root);
        if (parts.size() != 2 || !Bil.isBil(parts.get(0), "context") || !Bil.isBil(parts.get(1), "types")) {
            throw ProtocolException.malformed("missing_element", "description must hold bil:context then bil:types");
        }
        Control.Fields f = new Control.Fields(parts.get(0));
        String id = f.text("EntityID");
        String api = f.text("APIName");
        String type = f.text("EntityType");
        String ctx = f.text("Context");
        List<Component> comps = new ArrayList<>();
        for (Element c : Bil.children(parts.get(1))) {
            if (!Bil.isBil(c, "Component")) {
                throw ProtocolException.malformed("wrong_root", "bil:types holds " + c.getLocalName());
            }
            Iterator<Element> it = Bil.children(c).iterator();
            Element e = it.hasNext() ? it.next() : null;
            if (e == null || !Bil.isField(e, "ComponentID")) {
                throw Bil.missing("Component", "ComponentID", e);
            }
            String cid = Bil.text(e);
            List<Service> services = new ArrayList<>();
            List<Service> consumes = new ArrayList<>();
            while (it.hasNext()) {
                e = it.next();
                if (Bil.isField(e, "Service") && consumes.isEmpty()) {
                    services.add(service(e));
                } else if (Bil.isField(e, "Consumes")) {
                    consumes.add(service(e));
                } else {
                    throw ProtocolException.malformed("malformed", "Component " + cid + ": unexpected " + e.getLocalName());
                }
            }
            try {
                comps.add(new Component(cid, services, consumes));
            } catch (IllegalArgumentException ex) {
                throw ProtocolException.malformed("bad_value", ex.getMessage());
            }
        }
        try {
            return new Description(id, api, type, ctx, comps);
        } catch (IllegalArgumentException ex) {
            throw ProtocolException.malformed("bad_value", ex.getMessage());
        }
    }

    private static Service service(Element e) throws ProtocolException {
        Control.Fields f = new Control.Fields(e);
        String cat = f.text("ServiceCategory");
        String type = f.text("ServiceType");
        List<Param> ps = new ArrayList<>();
        List<Element> rest = Bil.children(e);
        if (rest.size() > 2 && Bil.isField(rest.get(2), "ServiceParameters")) {
            java.util.Set<String> seen = new java.util.HashSet<>();
            for (Element p : Bil.children(rest.get(2))) {
                if (p.getNamespaceURI() != null) {
                    throw ProtocolException.malformed("wrong_namespace", "parameter in a namespace: " + p.getLocalName());
                }
                if (!seen.add(p.getLocalName())) {
                    throw ProtocolException.malformed("duplicate_element", "parameter " + p.getLocalName() + " twice");
                }
                ps.add(new Param(p.getLocalName(), Bil.text(p)));
            }
        }
        return new Service(cat, type, ps);
    }
}

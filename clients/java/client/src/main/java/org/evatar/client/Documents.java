package org.evatar.client;

import org.w3c.dom.Element;

/** Tells a document by its root and decodes it: a {@link Signal}, a {@link Control} or a description. */
public final class Documents {
    private Documents() {}

    /** A description document, kept as its text with the entity id read from it. */
    public record DescriptionDoc(String entityId, String entityType, String xml) {}

    public static Object decode(byte[] bytes) throws ProtocolException {
        Element root = Bil.parse(bytes);
        String name = root.getLocalName();
        if (name.equals("Envelope")) {
            return Signal.decode(root);
        }
        if (name.equals("description")) {
            return Description.decodeHead(root, new String(bytes, java.nio.charset.StandardCharsets.UTF_8));
        }
        if (Control.isControl(name)) {
            return Control.decode(root);
        }
        throw ProtocolException.malformed("wrong_root", "unknown document bil:" + name);
    }
}

package org.evatar.client;

import java.io.ByteArrayInputStream;
import java.nio.ByteBuffer;
import java.nio.charset.CharacterCodingException;
import java.nio.charset.CodingErrorAction;
import java.nio.charset.StandardCharsets;
import java.util.ArrayList;
import java.util.List;
import javax.xml.XMLConstants;
import javax.xml.parsers.DocumentBuilder;
import javax.xml.parsers.DocumentBuilderFactory;
import javax.xml.parsers.ParserConfigurationException;
import org.w3c.dom.Document;
import org.w3c.dom.Element;
import org.w3c.dom.Node;
import org.xml.sax.SAXParseException;
import org.xml.sax.helpers.DefaultHandler;

/**
 * BIL documents as XML (docs/bil.md): a parser that refuses DOCTYPEs, entities
 * other than the five predefined ones, bad UTF-8 and excessive depth, and the
 * small helpers the codecs share.
 */
public final class Bil {
    /** The BIL namespace; field elements are in no namespace. */
    public static final String NS = "urn:evatar:bil:1";
    /** Deepest element nesting accepted (docs/protocol.md section 7). */
    public static final int MAX_DEPTH = 32;

    private static final DocumentBuilderFactory FACTORY = factory();

    private Bil() {}

    private static DocumentBuilderFactory factory() {
        DocumentBuilderFactory f = DocumentBuilderFactory.newInstance();
        f.setNamespaceAware(true);
        f.setXIncludeAware(false);
        f.setExpandEntityReferences(false);
        f.setCoalescing(true);
        f.setIgnoringComments(true);
        try {
            f.setFeature(XMLConstants.FEATURE_SECURE_PROCESSING, true);
            f.setFeature("http://apache.org/xml/features/disallow-doctype-decl", true);
            f.setFeature("http://xml.org/sax/features/external-general-entities", false);
            f.setFeature("http://xml.org/sax/features/external-parameter-entities", false);
            f.setFeature("http://apache.org/xml/features/nonvalidating/load-external-dtd", false);
        } catch (ParserConfigurationException e) {
            throw new IllegalStateException("this JDK's XML parser cannot be made safe", e);
        }
        f.setAttribute(XMLConstants.ACCESS_EXTERNAL_DTD, "");
        f.setAttribute(XMLConstants.ACCESS_EXTERNAL_SCHEMA, "");
        return f;
    }

    /**
     * Parses one document. Throws {@link ProtocolException} with class
     * {@code Malformed} for anything that is not a well-formed, DOCTYPE-free,
     * UTF-8 XML document with a root in the BIL namespace.
     */
    public static Element parse(byte[] bytes) throws ProtocolException {
        try {
            StandardCharsets.UTF_8.newDecoder()
                    .onMalformedInput(CodingErrorAction.REPORT)
                    .onUnmappableCharacter(CodingErrorAction.REPORT)
                    .decode(ByteBuffer.wrap(bytes));
        } catch (CharacterCodingException e) {
            throw ProtocolException.malformed("bad_encoding", "not UTF-8");
        }
        Document doc;
        try {
            DocumentBuilder b = FACTORY.newDocumentBuilder();
            b.setEntityResolver((publicId, systemId) -> {
                throw new SAXParseException("external entity refused: " + systemId, null);
            });
            b.setErrorHandler(new DefaultHandler() {
                @Override
                public void error(SAXParseException e) throws SAXParseException { throw e; }
            });
            doc = b.parse(new ByteArrayInputStream(bytes));
        } catch (SAXParseException e) {
            throw ProtocolException.malformed(classify(e.getMessage()),
                    "line " + e.getLineNumber() + ": " + e.getMessage());
        } catch (Exception e) {
            throw ProtocolException.malformed("malformed", String.valueOf(e.getMessage()));
        }
        if (doc.getDoctype() != null) {
            throw ProtocolException.malformed("doctype_refused", "DOCTYPE not allowed");
        }
        Element root = doc.getDocumentElement();
        checkDepth(root, 1);
        if (!NS.equals(root.getNamespaceURI())) {
            throw ProtocolException.malformed("wrong_namespace", "root element not in namespace " + NS);
        }
        return root;
    }

    /** The JDK parser's messages, told apart as well as its wording allows. */
    private static String classify(String m) {
        String s = m == null ? "" : m;
        if (s.contains("DOCTYPE")) {
            return "doctype_refused";
        }
        if (s.contains("entity") && s.contains("referenced")) {
            return "entity_refused";
        }
        if (s.contains("Invalid byte") || s.contains("invalid XML character") || s.contains("UTF-8")) {
            return "bad_encoding";
        }
        if (s.contains("must start and end within the same entity") || s.contains("Premature end of file")) {
            return "truncated";
        }
        return "malformed";
    }

    private static void checkDepth(Element e, int depth) throws ProtocolException {
        if (depth > MAX_DEPTH) {
            throw ProtocolException.malformed("too_deep", "elements nested deeper than " + MAX_DEPTH);
        }
        for (Element c : children(e)) {
            checkDepth(c, depth + 1);
        }
    }

    /** The element children of {@code e}, in order. */
    public static List<Element> children(Element e) {
        List<Element> out = new ArrayList<>();
        for (Node n = e.getFirstChild(); n != null; n = n.getNextSibling()) {
            if (n.getNodeType() == Node.ELEMENT_NODE) {
                out.add((Element) n);
            }
        }
        return out;
    }

    /** True when {@code e} is {@code bil:name}. */
    public static boolean isBil(Element e, String name) {
        return NS.equals(e.getNamespaceURI()) && name.equals(e.getLocalName());
    }

    /** True when {@code e} is the field {@code name} (no namespace). */
    public static boolean isField(Element e, String name) {
        return e.getNamespaceURI() == null && name.equals(e.getLocalName());
    }

    /** The text of a field element; an element child is an error. */
    public static String text(Element e) throws ProtocolException {
        StringBuilder sb = new StringBuilder();
        for (Node n = e.getFirstChild(); n != null; n = n.getNextSibling()) {
            switch (n.getNodeType()) {
                case Node.TEXT_NODE, Node.CDATA_SECTION_NODE -> sb.append(n.getNodeValue());
                case Node.ELEMENT_NODE -> throw ProtocolException.malformed(
                        "bad_value", "element " + e.getLocalName() + " must hold text only");
                case Node.ENTITY_REFERENCE_NODE -> throw ProtocolException.malformed(
                        "entity_refused", "unknown entity in " + e.getLocalName());
                default -> { }
            }
        }
        return sb.toString();
    }

    /** Escapes text for element content. */
    public static String escape(String s) {
        StringBuilder sb = new StringBuilder(s.length() + 8);
        for (int i = 0; i < s.length(); i++) {
            char c = s.charAt(i);
            switch (c) {
                case '&' -> sb.append("&amp;");
                case '<' -> sb.append("&lt;");
                case '>' -> sb.append("&gt;");
                case '\r' -> sb.append("&#13;");
                default -> sb.append(c);
            }
        }
        return sb.toString();
    }

    /** Appends {@code <name>text</name>}. */
    static void field(StringBuilder sb, String name, String text) {
        sb.append('<').append(name).append('>').append(escape(text)).append("</").append(name).append('>');
    }

    /** A number field: 1 to 20 decimal digits. */
    static long number(Element e) throws ProtocolException {
        String t = text(e);
        if (t.isEmpty() || t.length() > 20 || !t.chars().allMatch(c -> c >= '0' && c <= '9')) {
            throw ProtocolException.malformed("bad_value", e.getLocalName() + " is not a number: " + t);
        }
        try {
            return Long.parseLong(t);
        } catch (NumberFormatException ex) {
            throw ProtocolException.malformed("bad_value", e.getLocalName() + " is over 2^63-1: " + t);
        }
    }

    /** Refuses an element where field {@code name} should be (or nothing). */
    static ProtocolException missing(String where, String name, Element found) {
        if (found != null && name.equals(found.getLocalName()) && found.getNamespaceURI() != null) {
            return ProtocolException.malformed("wrong_namespace", where + ": field " + name
                    + " must be in no namespace, not " + found.getNamespaceURI());
        }
        return ProtocolException.malformed("missing_element", where + ": " + name + " missing"
                + (found == null ? "" : " (found " + found.getLocalName() + ")"));
    }

    /** True for a legal XML element name as BIL uses them (parameter names). */
    public static boolean isName(String s) {
        if (s == null || s.isEmpty()) {
            return false;
        }
        for (int i = 0; i < s.length(); i++) {
            char c = s.charAt(i);
            boolean ok = Character.isLetter(c) || c == '_'
                    || (i > 0 && (Character.isDigit(c) || c == '-' || c == '.'));
            if (!ok) {
                return false;
            }
        }
        return !s.regionMatches(true, 0, "xml", 0, 3);
    }
}

package org.evatar.client;

import static org.junit.jupiter.api.Assertions.assertArrayEquals;
import static org.junit.jupiter.api.Assertions.assertEquals;
import static org.junit.jupiter.api.Assertions.assertThrows;
import static org.junit.jupiter.api.Assertions.assertTrue;

import java.io.ByteArrayInputStream;
import java.io.EOFException;
import java.nio.charset.StandardCharsets;
import java.util.List;
import org.junit.jupiter.api.Test;

/** The codecs without a node: safety of the XML parser, frames, round trips. */
class CodecTest {
    static byte[] utf8(String s) {
        return s.getBytes(StandardCharsets.UTF_8);
    }

    @Test
    void externalEntitiesAreNeverFetched() {
        String xxe = "<?xml version=\"1.0\"?><!DOCTYPE h [<!ENTITY e SYSTEM \"file:///etc/passwd\">]>"
                + "<bil:Bye xmlns:bil=\"urn:evatar:bil:1\"><Reason>&e;</Reason></bil:Bye>";
        ProtocolException e = assertThrows(ProtocolException.class, () -> Documents.decode(utf8(xxe)));
        assertEquals("doctype_refused", e.kind());
        assertEquals("Malformed", e.code());
        assertTrue(!e.getMessage().contains("root:"), e.getMessage());
    }

    @Test
    void billionLaughsIsRefusedAtTheDoctype() {
        StringBuilder sb = new StringBuilder("<!DOCTYPE l [<!ENTITY l0 \"ha\">");
        for (int i = 1; i < 10; i++) {
            sb.append("<!ENTITY l").append(i).append(" \"").append(("&l" + (i - 1) + ";").repeat(10)).append("\">");
        }
        sb.append("]><bil:Bye xmlns:bil=\"urn:evatar:bil:1\"><Reason>&l9;</Reason></bil:Bye>");
        ProtocolException e = assertThrows(ProtocolException.class, () -> Documents.decode(utf8(sb.toString())));
        assertEquals("doctype_refused", e.kind());
    }

    @Test
    void anHttpRequestIsRefusedFromItsFirstFourBytes() {
        // Only the 4 bytes: the body is never awaited.
        ByteArrayInputStream in = new ByteArrayInputStream(utf8("GET "));
        ProtocolException e = assertThrows(ProtocolException.class, () -> Frames.read(in, Frames.HANDSHAKE_MAX));
        assertEquals("FrameTooLarge", e.code());
        assertTrue(e.getMessage().contains("1195725856"), e.getMessage());
    }

    @Test
    void framesAreBigEndianLengthThenDocument() throws Exception {
        byte[] doc = new Control.Bye(null).toBytes();
        byte[] f = Frames.encode(doc);
        assertEquals(doc.length + 4, f.length);
        assertEquals(0, f[0]);
        assertEquals(doc.length, f[3] & 0xff);
        assertArrayEquals(doc, Frames.decode(f, 100));
        assertThrows(EOFException.class, () -> Frames.decode(java.util.Arrays.copyOf(f, f.length - 1), 100));
        assertThrows(ProtocolException.class, () -> Frames.decode(f, doc.length - 1));
        assertThrows(IllegalArgumentException.class, () -> Frames.encode(new byte[0]));
    }

    @Test
    void signalsRoundTripWithEscapesAndUnicode() throws Exception {
        Signal s = Signal.builder().id("a&b<c>").context(Signal.SENSOR_DATA).sender("S").receiver("R")
                .timestamp(1763800000000L).sequence(7L).epoch(2L).service("SENSOR", "Say")
                .param("Text", "1 < 2 & 3 > 2\r\nnew line \"q\" 'a'").param("Unicode", "Grüße 世界 🙂").build();
        String xml = s.encode();
        assertTrue(xml.contains("&#13;"), xml);
        assertEquals(s, Documents.decode(utf8(xml)));
    }

    @Test
    void unknownContextsAndDuplicateParametersAreRefused() {
        Signal s = Signal.builder().id("1").context("Gossip").sender("S").receiver("R").timestamp(1)
                .service("A", "B").build();
        ProtocolException e = assertThrows(ProtocolException.class, () -> Documents.decode(s.toBytes()));
        assertEquals("bad_value", e.kind());
        String dup = Signal.builder().id("1").context(Signal.EVENT).sender("S").receiver("R").timestamp(1)
                .service("A", "B").param("X", "1").param("X", "2").build().encode();
        assertEquals("duplicate_element",
                assertThrows(ProtocolException.class, () -> Documents.decode(utf8(dup))).kind());
    }

    @Test
    void parameterNamesMustBeElementNames() {
        assertThrows(IllegalArgumentException.class, () -> new Param("1st", "x"));
        assertThrows(IllegalArgumentException.class, () -> new Param("a b", "x"));
        assertThrows(IllegalArgumentException.class, () -> new Param("xmlThing", "x"));
        assertEquals("Room", new Param("Room", "hall").name());
    }

    @Test
    void descriptionsRoundTrip() throws Exception {
        Description d = Bodies.va("va-x");
        assertEquals(d, Description.parse(d.toBytes()));
        assertEquals(List.of("LightEmulator01", "MotionEmulator01"),
                d.components().stream().map(Description.Component::id).toList());
    }
}

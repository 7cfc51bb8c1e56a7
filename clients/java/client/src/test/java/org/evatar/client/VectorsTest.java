package org.evatar.client;

import static org.junit.jupiter.api.Assertions.assertArrayEquals;
import static org.junit.jupiter.api.Assertions.assertEquals;
import static org.junit.jupiter.api.Assertions.assertInstanceOf;
import static org.junit.jupiter.api.Assertions.assertNotNull;
import static org.junit.jupiter.api.Assertions.assertTrue;
import static org.junit.jupiter.api.Assertions.fail;

import com.google.gson.JsonArray;
import com.google.gson.JsonElement;
import com.google.gson.JsonNull;
import com.google.gson.JsonObject;
import com.google.gson.JsonParser;
import com.google.gson.JsonPrimitive;
import java.io.EOFException;
import java.io.IOException;
import java.io.InputStream;
import java.io.OutputStream;
import java.net.Socket;
import java.net.SocketTimeoutException;
import java.nio.charset.StandardCharsets;
import java.nio.file.Files;
import java.nio.file.Path;
import java.util.ArrayList;
import java.util.List;
import java.util.stream.Stream;
import org.junit.jupiter.api.AfterAll;
import org.junit.jupiter.api.DynamicTest;
import org.junit.jupiter.api.TestFactory;

/**
 * The shared vectors of test/vectors (README.md there says how each kind is
 * checked), with the Java implementation. Error vectors run against a real
 * node (pairing {@code vectors}), one after the other.
 *
 * <p>Refusal classes: the JDK's XML parser is told apart by its messages
 * (Bil.classify); every invalid vector must be refused, and its class must be
 * the expected one.
 */
class VectorsTest {
    static final Path DIR = LocalNode.repo().resolve("test/vectors");
    static LocalNode node;

    @AfterAll
    static void stop() {
        if (node != null) {
            node.close();
        }
    }

    static synchronized LocalNode node() throws IOException {
        if (node == null) {
            node = LocalNode.start("vectors:va-secret:avatar-secret");
        }
        return node;
    }

    @TestFactory
    Stream<DynamicTest> vectors() throws IOException {
        JsonObject all = JsonParser.parseString(Files.readString(DIR.resolve("vectors.json"))).getAsJsonObject();
        assertEquals(1, all.get("version").getAsInt());
        List<DynamicTest> tests = new ArrayList<>();
        for (JsonElement e : all.getAsJsonArray("vectors")) {
            JsonObject v = e.getAsJsonObject();
            String name = v.get("name").getAsString();
            tests.add(DynamicTest.dynamicTest(name, () -> check(v)));
        }
        return tests.stream();
    }

    static byte[] bytes(String file) throws IOException {
        return Files.readAllBytes(DIR.resolve(file));
    }

    static void check(JsonObject v) throws Exception {
        String kind = v.get("kind").getAsString();
        switch (kind) {
            case "frame" -> frame(v);
            case "signal", "control", "description" -> document(v, kind);
            case "invalid" -> invalid(v);
            case "transcript" -> transcript(v);
            case "error" -> error(v);
            default -> fail("unknown kind " + kind);
        }
    }

    static void frame(JsonObject v) throws Exception {
        byte[] wire = bytes(v.get("file").getAsString());
        JsonObject x = v.getAsJsonObject("expect");
        byte[] doc = bytes(x.get("document").getAsString());
        byte[] got = Frames.decode(wire, Frames.DEFAULT_MAX);
        assertEquals(x.get("length").getAsInt(), got.length);
        assertArrayEquals(doc, got);
        assertArrayEquals(wire, Frames.encode(doc));
        assertArrayEquals(doc, encode(meaning(Documents.decode(doc))));
    }

    static void document(JsonObject v, String kind) throws Exception {
        byte[] doc = bytes(v.get("file").getAsString());
        JsonObject expect = v.getAsJsonObject("expect");
        JsonObject m = meaning(Documents.decode(doc));
        assertEquals(expect, m);
        assertEquals(kind, kindOf(m));
        byte[] enc = encode(expect);
        assertEquals(expect, meaning(Documents.decode(enc)));
        if (v.get("canonical").getAsBoolean()) {
            assertEquals(new String(doc, StandardCharsets.UTF_8), new String(enc, StandardCharsets.UTF_8));
            assertArrayEquals(doc, enc);
        }
    }

    static String kindOf(JsonObject m) {
        return m.has("control") ? "control" : m.has("components") ? "description" : "signal";
    }

    static void invalid(JsonObject v) {
        String file = v.get("file").getAsString();
        String want = v.getAsJsonObject("expect").get("error").getAsString();
        String got;
        try {
            byte[] b = bytes(file);
            if (file.startsWith("frames/")) {
                Frames.decode(b, Frames.HANDSHAKE_MAX);
            } else {
                Documents.decode(b);
            }
            got = "accepted";
        } catch (EOFException e) {
            got = "truncated_frame";
        } catch (ProtocolException e) {
            got = e.kind();
        } catch (Exception e) {
            got = "crash " + e;
        }
        assertEquals(want, got, file);
    }

    static void transcript(JsonObject v) throws Exception {
        JsonArray steps = v.getAsJsonArray("steps");
        assertTrue(steps.size() > 0);
        for (JsonElement s : steps) {
            JsonObject step = s.getAsJsonObject();
            byte[] doc = Frames.decode(bytes(step.get("file").getAsString()), Frames.DEFAULT_MAX);
            JsonObject expect = step.getAsJsonObject("expect");
            assertEquals(expect, meaning(Documents.decode(doc)), step.get("file").getAsString());
            assertEquals(new String(doc, StandardCharsets.UTF_8), new String(encode(expect), StandardCharsets.UTF_8));
        }
    }

    static void error(JsonObject v) throws Exception {
        LocalNode n = node();
        String setup = v.get("setup").isJsonNull() ? null : v.get("setup").getAsString();
        EvatarClient other = null;
        if (setup != null) {
            boolean agent = setup.equals("agent_connected");
            other = EvatarClient.connect(new EvatarClient.Options().pairing("vectors")
                    .role(agent ? "agent" : "avatar").entityId(agent ? "va-1" : "7008")
                    .credential(agent ? "va-secret" : "avatar-secret").endpoint(n.host(), n.port()), null);
        }
        JsonObject x = v.getAsJsonObject("expect");
        try (Socket s = new Socket(n.host(), n.port())) {
            s.setSoTimeout(10000);
            OutputStream out = s.getOutputStream();
            InputStream in = s.getInputStream();
            out.write(bytes(v.get("file").getAsString()));
            out.flush();
            Object answer;
            do {
                byte[] doc = Frames.read(in, Frames.DEFAULT_MAX);
                assertNotNull(doc, "closed without an answer");
                answer = Documents.decode(doc);
            } while (answer instanceof Control.Welcome);
            String code = x.get("error").getAsString();
            if (x.get("close").getAsBoolean()) {
                Control.Refused r = assertInstanceOf(Control.Refused.class, answer);
                assertEquals(code, r.code());
                assertClosed(in);
            } else {
                Signal e = assertInstanceOf(Signal.class, answer);
                assertEquals(Signal.ERROR, e.context());
                assertEquals("ERROR", e.category());
                assertEquals(code, e.type());
                assertEquals("EVATAR", e.sender());
                assertTrue(e.param("Message").isPresent());
                Frames.write(out, new Control.Bye(null).toBytes());
                Object bye;
                do {
                    bye = Documents.decode(Frames.read(in, Frames.DEFAULT_MAX));
                } while (!(bye instanceof Control.Bye));
                assertClosed(in);
            }
        } finally {
            if (other != null) {
                other.close();
            }
        }
    }

    static void assertClosed(InputStream in) throws IOException {
        try {
            while (true) {
                byte[] doc = Frames.read(in, Frames.DEFAULT_MAX);
                if (doc == null) {
                    return;
                }
            }
        } catch (SocketTimeoutException e) {
            fail("the server did not close the connection");
        } catch (IOException | ProtocolException e) {
            // A reset is a close too.
        }
    }

    // ------------------------------------------------------------------ meanings

    static JsonElement str(String s) {
        return s == null ? JsonNull.INSTANCE : new JsonPrimitive(s);
    }

    static JsonElement num(Long n) {
        return n == null ? JsonNull.INSTANCE : new JsonPrimitive(n);
    }

    static JsonArray params(List<Param> ps) {
        JsonArray a = new JsonArray();
        for (Param p : ps) {
            JsonObject o = new JsonObject();
            o.addProperty("name", p.name());
            o.addProperty("value", p.value());
            a.add(o);
        }
        return a;
    }

    static JsonObject meaning(Object d) {
        JsonObject m = new JsonObject();
        if (d instanceof Signal s) {
            m.addProperty("context", s.context());
            m.addProperty("id", s.id());
            m.addProperty("sender", s.sender());
            m.addProperty("receiver", s.receiver());
            m.add("in_reply_to", str(s.inReplyTo()));
            m.addProperty("timestamp", s.timestamp());
            m.add("sequence", num(s.sequence()));
            m.add("epoch", num(s.epoch()));
            m.add("origin", str(s.origin()));
            JsonObject svc = new JsonObject();
            svc.addProperty("category", s.category());
            svc.addProperty("type", s.type());
            m.add("service", svc);
            m.add("parameters", params(s.parameters()));
        } else if (d instanceof Description desc) {
            m.addProperty("entity_id", desc.entityId());
            m.addProperty("api_name", desc.apiName());
            m.addProperty("entity_type", desc.entityType());
            m.addProperty("context", desc.context());
            JsonArray cs = new JsonArray();
            for (Description.Component c : desc.components()) {
                JsonObject co = new JsonObject();
                co.addProperty("id", c.id());
                co.add("services", entries(c.services()));
                co.add("consumes", entries(c.consumes()));
                cs.add(co);
            }
            m.add("components", cs);
        } else if (d instanceof Documents.DescriptionDoc dd) {
            try {
                return meaning(Description.parse(dd.xml().getBytes(StandardCharsets.UTF_8)));
            } catch (ProtocolException e) {
                throw new AssertionError(e);
            }
        } else if (d instanceof Control c) {
            control(c, m);
        } else {
            fail("no meaning for " + d);
        }
        return m;
    }

    static JsonArray entries(List<Description.Service> ss) {
        JsonArray a = new JsonArray();
        for (Description.Service s : ss) {
            JsonObject o = new JsonObject();
            o.addProperty("category", s.category());
            o.addProperty("type", s.type());
            o.add("parameters", params(s.parameters()));
            a.add(o);
        }
        return a;
    }

    static void control(Control c, JsonObject m) {
        if (c instanceof Control.Hello h) {
            m.addProperty("control", "Hello");
            hello(m, h.pairing(), h.role(), h.entityId(), h.credential(), h.protocolVersion());
        } else if (c instanceof Control.Resume r) {
            m.addProperty("control", "Resume");
            hello(m, r.pairing(), r.role(), r.entityId(), r.credential(), 2);
            m.addProperty("session_id", r.sessionId());
            m.addProperty("received", r.received());
            m.addProperty("epoch", r.epoch());
        } else if (c instanceof Control.Welcome w) {
            m.addProperty("control", "Welcome");
            m.addProperty("pairing", w.pairing());
            m.addProperty("entity_id", w.entityId());
            m.addProperty("session_id", w.sessionId());
            m.addProperty("join_timeout", w.joinTimeout());
            m.addProperty("max_frame", w.maxFrame());
            m.add("epoch", num(w.epoch()));
            m.add("resumed", w.resumed() == null ? JsonNull.INSTANCE : new JsonPrimitive(w.resumed()));
            m.add("last_accepted", w.isVersion2() ? str(w.lastAccepted() == null ? "" : w.lastAccepted()) : JsonNull.INSTANCE);
            m.add("dedup_window", num(w.dedupWindow()));
            m.add("heartbeat", num(w.heartbeat()));
        } else if (c instanceof Control.Ack a) {
            m.addProperty("control", "Ack");
            m.add("accepted", str(a.accepted()));
            m.add("received", num(a.received()));
        } else if (c instanceof Control.Refused r) {
            m.addProperty("control", "Refused");
            m.addProperty("code", r.code());
            m.addProperty("message", r.message());
        } else if (c instanceof Control.Bye b) {
            m.addProperty("control", "Bye");
            m.addProperty("reason", b.reason() == null ? "" : b.reason());
        } else if (c instanceof Control.GetBinding) {
            m.addProperty("control", "GetBinding");
        } else if (c instanceof Control.Binding b) {
            m.addProperty("control", "Binding");
            JsonArray es = new JsonArray();
            b.entities().forEach(es::add);
            m.add("entities", es);
            JsonArray bound = new JsonArray();
            for (Control.Bound r : b.bound()) {
                JsonObject o = new JsonObject();
                o.addProperty("consumer_entity", r.consumerEntity());
                o.addProperty("consumer_component", r.consumerComponent());
                o.addProperty("provider_entity", r.providerEntity());
                o.addProperty("provider_component", r.providerComponent());
                o.addProperty("service_category", r.category());
                o.addProperty("service_type", r.type());
                o.addProperty("score", r.score());
                o.addProperty("candidates", r.candidates());
                bound.add(o);
            }
            m.add("bound", bound);
            JsonArray unbound = new JsonArray();
            for (Control.Unbound u : b.unbound()) {
                JsonObject o = new JsonObject();
                o.addProperty("consumer_entity", u.consumerEntity());
                o.addProperty("consumer_component", u.consumerComponent());
                o.addProperty("service_category", u.category());
                o.addProperty("service_type", u.type());
                o.addProperty("reason", u.reason());
                unbound.add(o);
            }
            m.add("unbound", unbound);
        }
    }

    static void hello(JsonObject m, String p, String r, String e, String c, int v) {
        m.addProperty("pairing", p);
        m.addProperty("role", r);
        m.addProperty("entity_id", e);
        m.addProperty("credential", c);
        m.addProperty("protocol_version", v);
    }

    // ------------------------------------------------------------------ encoding a meaning

    static String s(JsonObject o, String k) {
        JsonElement e = o.get(k);
        return e == null || e.isJsonNull() ? null : e.getAsString();
    }

    static Long l(JsonObject o, String k) {
        JsonElement e = o.get(k);
        return e == null || e.isJsonNull() ? null : e.getAsLong();
    }

    static List<Param> ps(JsonArray a) {
        List<Param> out = new ArrayList<>();
        for (JsonElement e : a) {
            out.add(new Param(s(e.getAsJsonObject(), "name"), s(e.getAsJsonObject(), "value")));
        }
        return out;
    }

    static List<Description.Service> svcs(JsonArray a) {
        List<Description.Service> out = new ArrayList<>();
        for (JsonElement e : a) {
            JsonObject o = e.getAsJsonObject();
            out.add(new Description.Service(s(o, "category"), s(o, "type"), ps(o.getAsJsonArray("parameters"))));
        }
        return out;
    }

    static byte[] encode(JsonObject m) {
        switch (kindOf(m)) {
            case "signal" -> {
                JsonObject svc = m.getAsJsonObject("service");
                return new Signal(s(m, "id"), s(m, "context"), s(m, "sender"), s(m, "receiver"), s(m, "in_reply_to"),
                        l(m, "timestamp"), l(m, "sequence"), l(m, "epoch"), s(svc, "category"), s(svc, "type"),
                        ps(m.getAsJsonArray("parameters")), s(m, "origin")).toBytes();
            }
            case "description" -> {
                List<Description.Component> cs = new ArrayList<>();
                for (JsonElement e : m.getAsJsonArray("components")) {
                    JsonObject c = e.getAsJsonObject();
                    cs.add(new Description.Component(s(c, "id"), svcs(c.getAsJsonArray("services")),
                            svcs(c.getAsJsonArray("consumes"))));
                }
                return new Description(s(m, "entity_id"), s(m, "api_name"), s(m, "entity_type"), s(m, "context"), cs)
                        .toBytes();
            }
            default -> {
                return control(m).toBytes();
            }
        }
    }

    static Control control(JsonObject m) {
        return switch (s(m, "control")) {
            case "Hello" -> new Control.Hello(s(m, "pairing"), s(m, "role"), s(m, "entity_id"), s(m, "credential"),
                    l(m, "protocol_version").intValue());
            case "Resume" -> new Control.Resume(s(m, "pairing"), s(m, "role"), s(m, "entity_id"), s(m, "credential"),
                    s(m, "session_id"), l(m, "received"), l(m, "epoch"));
            case "Welcome" -> new Control.Welcome(s(m, "pairing"), s(m, "entity_id"), s(m, "session_id"),
                    l(m, "join_timeout"), l(m, "max_frame"), l(m, "epoch"),
                    m.get("resumed").isJsonNull() ? null : m.get("resumed").getAsBoolean(),
                    s(m, "last_accepted"), l(m, "dedup_window"), l(m, "heartbeat"));
            case "Ack" -> new Control.Ack(s(m, "accepted"), l(m, "received"));
            case "Refused" -> new Control.Refused(s(m, "code"), s(m, "message"));
            case "Bye" -> new Control.Bye(s(m, "reason"));
            case "GetBinding" -> new Control.GetBinding();
            case "Binding" -> {
                List<String> es = new ArrayList<>();
                m.getAsJsonArray("entities").forEach(e -> es.add(e.getAsString()));
                List<Control.Bound> b = new ArrayList<>();
                for (JsonElement e : m.getAsJsonArray("bound")) {
                    JsonObject o = e.getAsJsonObject();
                    b.add(new Control.Bound(s(o, "consumer_entity"), s(o, "consumer_component"), s(o, "provider_entity"),
                            s(o, "provider_component"), s(o, "service_category"), s(o, "service_type"),
                            l(o, "score"), l(o, "candidates")));
                }
                List<Control.Unbound> u = new ArrayList<>();
                for (JsonElement e : m.getAsJsonArray("unbound")) {
                    JsonObject o = e.getAsJsonObject();
                    u.add(new Control.Unbound(s(o, "consumer_entity"), s(o, "consumer_component"),
                            s(o, "service_category"), s(o, "service_type"), s(o, "reason")));
                }
                yield new Control.Binding(es, b, u);
            }
            default -> throw new AssertionError("unknown control " + m);
        };
    }

}

package org.evatar.jason;

import static org.junit.jupiter.api.Assertions.assertEquals;

import java.io.IOException;
import java.nio.file.Files;
import java.nio.file.Path;
import java.time.Duration;
import java.util.List;
import java.util.concurrent.CopyOnWriteArrayList;
import java.util.concurrent.TimeUnit;
import org.evatar.client.Control;
import org.evatar.client.Description;
import org.evatar.client.EvatarClient;
import org.evatar.client.LocalNode;
import org.evatar.client.Param;
import org.evatar.client.Signal;
import org.junit.jupiter.api.Test;
import org.junit.jupiter.api.Timeout;
import org.junit.jupiter.api.io.TempDir;

/**
 * A Jason agent run by a real node's port connector (EvatarAgent's main with
 * --stdio): EVATAR starts and supervises the MAS process; its actions reach a
 * TCP Avatar and the feedback comes back as percepts.
 */
class JasonPortTest {
    static final String ASL = """
            +embodied : not asked <- +asked; request(on, "TurnLightOn", [], []).
            +feedback(on, _, ok, Ps) : .member(param("Light", L), Ps)
               <- request(off, "TurnLightOff", [], [param("After", L), param("Agent", "jason")]).
            +feedback(_, _, _, _).
            """;

    static Description.Service svc(String cat, String type, String name, String value) {
        return new Description.Service(cat, type, List.of(new Param(name, value)));
    }

    @Test
    @Timeout(value = 90, unit = TimeUnit.SECONDS)
    void jasonAgentStartedByTheNode(@TempDir Path dir) throws Exception {
        Path asl = dir.resolve("lamp.asl");
        Files.writeString(asl, ASL);
        Path body = dir.resolve("body.xml");
        Files.writeString(body, Description.agent("jason-va", List.of(new Description.Component("LightEmulator01",
                List.of(svc("ACTUATOR", "ACTION FEEDBACK", "Feedback", "yes")),
                List.of(svc("ACTUATOR", "TurnLightOn", "Light", "yes"),
                        svc("ACTUATOR", "TurnLightOff", "Light", "yes"))))).encode());
        List<Signal> requests = new CopyOnWriteArrayList<>();
        try (LocalNode node = LocalNode.startCtl("jp:va-jp:av-jp")) {
            EvatarClient[] lamp = new EvatarClient[1];
            lamp[0] = EvatarClient.connect(new EvatarClient.Options().pairing("jp").role("avatar").entityId("lamp")
                    .credential("av-jp").endpoint(node.host(), node.port()), new EvatarClient.Listener() {
                        @Override
                        public void onSignal(Signal s) {
                            if (!s.context().equals(Signal.REQUEST)) {
                                return;
                            }
                            requests.add(s);
                            try {
                                lamp[0].send(Signal.builder().context(Signal.FEEDBACK).sender(s.receiver())
                                        .receiver(s.sender()).inReplyTo(s.id()).service(s.category(), s.type())
                                        .param("Light", s.type().equals("TurnLightOn") ? "on" : "off"));
                            } catch (IOException e) {
                                throw new IllegalStateException(e);
                            }
                        }
                    });
            try (EvatarClient av = lamp[0]) {
                av.describe(Description.avatar("lamp", List.of(new Description.Component("Light01",
                        List.of(svc("ACTUATOR", "TurnLightOn", "Light", "yes"),
                                svc("ACTUATOR", "TurnLightOff", "Light", "yes")),
                        List.of(svc("ACTUATOR", "ACTION FEEDBACK", "Feedback", "yes"))))));
                String java = ProcessHandle.current().info().command().orElse("java");
                node.command(30, "port", "jason", java, "-cp", System.getProperty("java.class.path"),
                        EvatarAgent.class.getName(), asl.toString(), body.toString(), "jp", "jason-va", "va-jp",
                        "--stdio");
                Control.Binding b = av.awaitBinding(x -> x.entities().contains("jason-va"), Duration.ofSeconds(30));
                assertEquals("jason-va", b.entities().get(1));
                long end = System.nanoTime() + TimeUnit.SECONDS.toNanos(30);
                while (requests.size() < 2 && System.nanoTime() < end) {
                    Thread.sleep(20);
                }
                assertEquals(List.of("TurnLightOn", "TurnLightOff"), requests.stream().map(Signal::type).toList());
                assertEquals("on", requests.get(1).param("After").orElseThrow());
                assertEquals("jason", requests.get(1).param("Agent").orElseThrow());
                node.command(30, "stop_port", "jason");
                av.awaitBinding(x -> !x.entities().contains("jason-va"), Duration.ofSeconds(30));
            }
        }
    }
}

package org.evatar.client;

import static org.junit.jupiter.api.Assertions.assertEquals;
import static org.junit.jupiter.api.Assertions.assertTrue;

import java.time.Duration;
import java.util.List;
import java.util.concurrent.TimeUnit;
import org.junit.jupiter.api.Test;
import org.junit.jupiter.api.Timeout;

/**
 * A Java VA started by a real node's port connector (agent_bridge_port):
 * frames on its stdin/stdout, the node supervising the process.
 */
class PortConnectorTest {

    @Test
    @Timeout(value = 90, unit = TimeUnit.SECONDS)
    void javaAgentRunAsAPortTalksToATcpAvatar() throws Exception {
        try (LocalNode node = LocalNode.startCtl("ported:va-ported:av-ported")) {
            NodeClientTest.Lamp lamp = new NodeClientTest.Lamp();
            EvatarClient.Options o = new EvatarClient.Options().pairing("ported").role("avatar")
                    .entityId("lamp-p").credential("av-ported").endpoint(node.host(), node.port());
            try (EvatarClient av = EvatarClient.connect(o, lamp)) {
                lamp.client = av;
                av.describe(Bodies.avatar("lamp-p"));
                String java = ProcessHandle.current().info().command().orElse("java");
                node.command(30, "port", "java-va", java, "-cp", System.getProperty("java.class.path"),
                        PortAgentMain.class.getName(), "ported", "va-ported", "va-port");
                // The program joins through the node, binds, and asks the lamp twice.
                av.awaitBinding(b -> b.entities().contains("va-port"), Duration.ofSeconds(30));
                long end = System.nanoTime() + TimeUnit.SECONDS.toNanos(30);
                while (lamp.requests.size() < 2 && System.nanoTime() < end) {
                    Thread.sleep(20);
                }
                assertEquals(List.of("TurnLightOn", "TurnLightOff"),
                        lamp.requests.stream().map(Signal::type).toList());
                Signal second = lamp.requests.get(1);
                assertEquals("on", second.param("After").orElseThrow());
                assertEquals("stdio", second.param("Transport").orElseThrow());
                assertEquals("LightEmulator01", second.sender());
                assertTrue(node.command(10, "entities", "ported").get(0).contains("va-port"));
                // Stopping the port closes the program's stdin: it leaves the pairing.
                node.command(30, "stop_port", "java-va");
                av.awaitBinding(b -> !b.entities().contains("va-port"), Duration.ofSeconds(30));
                assertEquals("ENTITIES lamp-p", node.command(10, "entities", "ported").get(0));
            }
        }
    }
}

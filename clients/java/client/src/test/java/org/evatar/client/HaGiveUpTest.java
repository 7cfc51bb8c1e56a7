package org.evatar.client;

import static org.junit.jupiter.api.Assertions.assertEquals;
import static org.junit.jupiter.api.Assertions.assertThrows;
import static org.junit.jupiter.api.Assertions.assertTrue;

import java.time.Duration;
import java.util.List;
import java.util.concurrent.CompletableFuture;
import java.util.concurrent.CopyOnWriteArrayList;
import java.util.concurrent.ExecutionException;
import java.util.concurrent.TimeUnit;
import org.junit.jupiter.api.Test;
import org.junit.jupiter.api.Timeout;

/** A version 2 client whose only node stops for good gives up after its reconnect limit. */
class HaGiveUpTest {

    @Test
    @Timeout(value = 60, unit = TimeUnit.SECONDS)
    void givesUpWhenNoNodeComesBack() throws Exception {
        LocalNode node = LocalNode.start("gone:va-gone:av-gone");
        List<String> closed = new CopyOnWriteArrayList<>();
        EvatarClient va;
        try {
            va = EvatarClient.connect(new EvatarClient.Options().pairing("gone").role("agent").entityId("va-g")
                    .credential("va-gone").endpoint(node.host(), node.port()).ha(true)
                    // The handshake timeout only bounds this first connect (once the node has
                    // stopped, its port refuses at once): 500 ms failed it under load
                    // (HandshakeTimeout before the Welcome of a busy node).
                    .handshakeTimeout(Duration.ofSeconds(30)).reconnectLimit(Duration.ofSeconds(2)),
                    new EvatarClient.Listener() {
                        @Override
                        public void onClosed(String reason, Throwable cause) {
                            closed.add(reason);
                        }
                    });
            va.describe(Bodies.va("va-g"));
        } finally {
            node.close();
        }
        // A request waits across reconnects, and fails when the client gives up.
        CompletableFuture<Signal> f = va.request(Signal.builder().sender("LightEmulator01")
                .receiver("HomeLightActuator01").service("ACTUATOR", "TurnLightOn"));
        assertEquals("gave_up", va.awaitClosed(Duration.ofSeconds(30)));
        assertEquals(List.of("gave_up"), closed);
        ExecutionException e = assertThrows(ExecutionException.class, () -> f.get(5, TimeUnit.SECONDS));
        assertTrue(e.getCause().getMessage().contains("gave_up"), e.getCause().getMessage());
        assertEquals(1, va.unacknowledged());
    }
}

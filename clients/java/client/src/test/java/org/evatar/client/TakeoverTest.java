package org.evatar.client;

import static org.junit.jupiter.api.Assertions.assertEquals;
import static org.junit.jupiter.api.Assertions.assertTrue;

import java.time.Duration;
import java.util.List;
import java.util.concurrent.CompletableFuture;
import java.util.concurrent.CopyOnWriteArrayList;
import java.util.concurrent.TimeUnit;
import org.junit.jupiter.api.Timeout;
import org.junit.jupiter.params.ParameterizedTest;
import org.junit.jupiter.params.provider.ValueSource;

/**
 * Protocol version 2 across a real takeover: two EVATAR nodes in a cluster
 * (scripts/test-node-ctl.sh --cluster 2), the pairing active on node 1 with
 * its standby on node 2; node 1 is killed (kill -9) or frozen (kill -STOP: it
 * still accepts TCP connections but says nothing, so the clients must notice
 * the silence) and both clients resume their sessions on node 2, losing
 * nothing EVATAR had accepted.
 */
class TakeoverTest {

    @ParameterizedTest
    @ValueSource(strings = {"kill", "freeze"})
    @Timeout(value = 120, unit = TimeUnit.SECONDS)
    void sessionsSurviveTheActiveNode(String fault) throws Exception {
        try (LocalNode cluster = LocalNode.startCtl("ha:va-ha:av-ha", "--cluster", "2")) {
            List<Integer> ports = cluster.ports();
            assertEquals(2, ports.size());
            NodeClientTest.Lamp lamp = new NodeClientTest.Lamp();
            List<Signal> readings = new CopyOnWriteArrayList<>();
            List<String> reconnects = new CopyOnWriteArrayList<>();
            EvatarClient.Options ao = new EvatarClient.Options().pairing("ha").role("avatar").entityId("lamp-ha")
                    .credential("av-ha").ha(true).handshakeTimeout(Duration.ofSeconds(1));
            EvatarClient.Options vo = new EvatarClient.Options().pairing("ha").role("agent").entityId("va-ha")
                    .credential("va-ha").ha(true).handshakeTimeout(Duration.ofSeconds(1));
            for (int p : ports) {
                ao.endpoint("127.0.0.1", p);
                vo.endpoint("127.0.0.1", p);
            }
            try (EvatarClient av = EvatarClient.connect(ao, lamp);
                 EvatarClient va = EvatarClient.connect(vo, new EvatarClient.Listener() {
                     @Override
                     public void onSignal(Signal s) {
                         if (s.context().equals(Signal.SENSOR_DATA)) {
                             readings.add(s);
                         }
                     }

                     @Override
                     public void onReconnected(String endpoint, boolean resumed, long epoch) {
                         reconnects.add(endpoint + " resumed=" + resumed + " epoch=" + epoch);
                     }
                 })) {
                lamp.client = av;
                av.describe(Bodies.avatar("lamp-ha"));
                va.describe(Bodies.va("va-ha"));
                va.awaitBinding(b -> Bodies.lightBound(b, "va-ha"), Duration.ofSeconds(10));
                av.awaitBinding(b -> !b.consumedBy("lamp-ha", "HallMotionSensor01").isEmpty(), Duration.ofSeconds(10));
                assertEquals(1L, va.welcome().epoch());
                ActuatorEmulator light = new ActuatorEmulator(va, "LightEmulator01");
                assertEquals("on", light.call("TurnLightOn", List.of(), Duration.ofSeconds(10))
                        .param("Light").orElseThrow());
                for (int i = 0; i < 50; i++) {
                    av.send(Signal.builder().context(Signal.SENSOR_DATA).sender("HallMotionSensor01")
                            .receiver("MotionEmulator01").service("SENSOR", "MotionDetected")
                            .param("Reading", Integer.toString(i)));
                }
                // Accepted means held by the standby too: these must survive the crash.
                assertTrue(av.awaitAcks(Duration.ofSeconds(10)));
                assertTrue(va.awaitAcks(Duration.ofSeconds(10)));

                cluster.command(10, fault, "1");
                CompletableFuture<Signal> off = light.request("TurnLightOff", List.of());
                assertEquals("off", off.get(60, TimeUnit.SECONDS).param("Light").orElseThrow());
                long end = System.nanoTime() + TimeUnit.SECONDS.toNanos(30);
                while (readings.size() < 50 && System.nanoTime() < end) {
                    Thread.sleep(20);
                }
                assertEquals(50, readings.size());
                for (int i = 0; i < 50; i++) {
                    assertEquals(Integer.toString(i), readings.get(i).param("Reading").orElseThrow());
                }
                assertEquals(2L, va.welcome().epoch(), reconnects.toString());
                assertTrue(reconnects.stream().anyMatch(r -> r.contains(":" + ports.get(1) + " resumed=true")),
                        reconnects.toString());
                assertEquals(List.of("TurnLightOn", "TurnLightOff"), lamp.requests.stream().map(Signal::type).toList());
                assertTrue(va.awaitAcks(Duration.ofSeconds(10)));
                assertEquals(null, va.closedReason());
                assertEquals(null, av.closedReason());
            }
        }
    }
}

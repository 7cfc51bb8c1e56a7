package org.evatar.client;

import java.time.Duration;
import java.util.List;

/**
 * A VA run by EVATAR's port connector: it speaks on stdin/stdout. Once bound
 * it asks the Avatar's light to turn on, then to turn off, telling in the
 * second request what the first one's feedback said and which transport it
 * used; then it waits until EVATAR closes its stdin.
 * Arguments: PAIRING CREDENTIAL ENTITY.
 */
public final class PortAgentMain {
    private PortAgentMain() {}

    public static void main(String[] args) throws Exception {
        Transport.redirectSystemOut();
        EvatarClient.Options o = new EvatarClient.Options().pairing(args[0]).credential(args[1])
                .entityId(args[2]).role("agent");
        EvatarClient c = EvatarClient.connectStdio(o, null);
        System.err.println("port agent " + args[2] + ": welcomed, session " + c.welcome().sessionId());
        c.describe(Bodies.va(args[2]));
        c.awaitBinding(b -> Bodies.lightBound(b, args[2]), Duration.ofSeconds(30));
        ActuatorEmulator light = new ActuatorEmulator(c, "LightEmulator01");
        Signal on = light.call("TurnLightOn", List.of(), Duration.ofSeconds(10));
        light.call("TurnLightOff", List.of(new Param("After", on.param("Light").orElse("?")),
                new Param("Transport", "stdio")), Duration.ofSeconds(10));
        System.err.println("port agent " + args[2] + ": done, waiting for EOF");
        String why = c.awaitClosed(Duration.ofMinutes(5));
        System.err.println("port agent " + args[2] + ": closed (" + why + ")");
        System.exit(0);
    }
}

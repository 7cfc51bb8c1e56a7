package org.evatar.client;

import java.util.List;

/** The small VA and Avatar bodies the tests use: a light and a motion sensor. */
final class Bodies {
    private Bodies() {}

    static Description.Service svc(String cat, String type, String... kv) {
        List<Param> ps = new java.util.ArrayList<>();
        for (int i = 0; i < kv.length; i += 2) {
            ps.add(new Param(kv[i], kv[i + 1]));
        }
        return new Description.Service(cat, type, ps);
    }

    static Description va(String id) {
        return Description.agent(id, List.of(
                new Description.Component("LightEmulator01",
                        List.of(svc("ACTUATOR", "ACTION FEEDBACK", "Feedback", "yes", "Device", "light")),
                        List.of(svc("ACTUATOR", "TurnLightOn", "Light", "yes"),
                                svc("ACTUATOR", "TurnLightOff", "Light", "yes"))),
                new Description.Component("MotionEmulator01",
                        List.of(svc("SENSOR", "MotionDetected", "Room", "hall")),
                        List.of(svc("SENSOR", "ReadMotion", "Motion", "yes")))));
    }

    static Description avatar(String id) {
        return Description.avatar(id, List.of(
                new Description.Component("HomeLightActuator01",
                        List.of(svc("ACTUATOR", "TurnLightOn", "Light", "yes"),
                                svc("ACTUATOR", "TurnLightOff", "Light", "yes")),
                        List.of(svc("ACTUATOR", "ACTION FEEDBACK", "Feedback", "yes", "Device", "light"))),
                new Description.Component("HallMotionSensor01",
                        List.of(svc("SENSOR", "ReadMotion", "Motion", "yes", "Room", "hall")),
                        List.of(svc("SENSOR", "MotionDetected", "Room", "hall")))));
    }

    /** True when the VA's light emulator is bound to the Avatar's light. */
    static boolean lightBound(Control.Binding b, String va) {
        return b.consumedBy(va, "LightEmulator01").stream()
                .anyMatch(r -> r.providerComponent().equals("HomeLightActuator01"));
    }
}

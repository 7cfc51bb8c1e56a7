"""A VA for the porch: when its motion sensor emulator perceives motion, it
asks its light actuator emulator to turn the light on, and says what the
Avatar answered. Start the Avatar (avatar.py) too; both find each other
through EVATAR's binding."""

import asyncio
import sys

from evatar import ActuatorEmulator, Client, Entry, SensorEmulator, describe


async def main(port: int) -> None:
    va = Client([("127.0.0.1", port)], pairing="porch", role="agent",
                entity_id="porch-va", credential="va-secret")
    # The emulators are the VA's body: one consumes the Avatar's TurnLightOn
    # service, one provides the MotionDetected service a sensor feeds.
    light = ActuatorEmulator(va, "LightEmulator",
                             [Entry("ACTUATOR", "TurnLightOn", {"Light": "yes"})])
    motion = SensorEmulator(va, "MotionEmulator", "MotionDetected", {"Room": "porch"})
    await va.connect()
    await describe(va, [light, motion], api_name="PORCH VA")
    print("VA: joined, waiting for motion", flush=True)
    while True:
        reading = await motion.reading()
        if reading.param("Motion") != "yes":
            continue
        feedback = await light.act("TurnLightOn", {"Light": "yes"}, timeout=5)
        print("VA: motion", reading.param("N"), "-> light says", feedback.param("Light"),
              flush=True)


if __name__ == "__main__":
    asyncio.run(main(int(sys.argv[1]) if len(sys.argv) > 1 else 7400))

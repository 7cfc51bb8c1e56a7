import asyncio
from evatar import ActuatorEmulator, Client, Entry, SensorEmulator, describe

async def main() -> None:
    va = Client([("127.0.0.1", 7400)], pairing="porch", role="agent",
                entity_id="porch-va", credential="va-secret")
    # The VA's body: an emulator consuming the Avatar's TurnLightOn service,
    # and one providing the MotionDetected service a motion sensor feeds.
    light = ActuatorEmulator(va, "LightEmulator",
                             [Entry("ACTUATOR", "TurnLightOn", {"Light": "yes"})])
    motion = SensorEmulator(va, "MotionEmulator", "MotionDetected", {"Room": "porch"})
    await va.connect()
    await describe(va, [light, motion], api_name="PORCH VA")
    print("VA: joined, waiting for motion", flush=True)
    while True:
        reading = await motion.reading()
        if reading.param("Motion") == "yes":
            feedback = await light.act("TurnLightOn", {"Light": "yes"}, timeout=10)
            print("VA: motion", reading.param("N"), "-> light says", feedback.param("Light"),
                  flush=True)

asyncio.run(main())

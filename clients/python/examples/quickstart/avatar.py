import asyncio
from evatar import Actuator, Client, Entry, Sensor, describe

def turn_on(request):            # returns the Feedback's parameters
    return {"Light": "on", "Done": "yes"}

async def main() -> None:
    porch = Client([("127.0.0.1", 7400)], pairing="porch", role="avatar",
                   entity_id="porch-01", credential="avatar-secret")
    lamp = Actuator(porch, "PorchLamp", [Entry("ACTUATOR", "TurnLightOn", {"Light": "yes"})],
                    turn_on)
    sensor = Sensor(porch, "PorchMotion", "MotionDetected", {"Room": "porch"})
    await porch.connect()
    await describe(porch, [lamp, sensor], api_name="PORCH")
    # Wait until EVATAR has bound the sensor to the VA's emulator.
    await porch.wait_binding(lambda b: sensor.is_bound("MotionDetected"), timeout=60)
    for n in range(1, 4):
        await sensor.emit({"Motion": "yes", "N": str(n)})
        await asyncio.sleep(1)
    print("Avatar: lamp handled", lamp.handled, "requests", flush=True)
    await porch.close()

asyncio.run(main())

"""A pretend porch: a lamp (an actuator answering TurnLightOn) and a motion
sensor that reports motion three times, one second apart."""

import asyncio
import sys

from evatar import Actuator, Client, Entry, Sensor, describe

lamp_on = False


def turn_on(request):
    global lamp_on
    lamp_on = True
    return {"Light": "on", "Done": "yes"}


async def main(port: int) -> None:
    porch = Client([("127.0.0.1", port)], pairing="porch", role="avatar",
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
    print("Avatar: lamp handled", lamp.handled, "requests; lamp on:", lamp_on, flush=True)
    await porch.close()


if __name__ == "__main__":
    asyncio.run(main(int(sys.argv[1]) if len(sys.argv) > 1 else 7400))

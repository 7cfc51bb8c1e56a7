import asyncio
import sys

from evatar import Component, Description, Entry
from evatar.spade import Body, EmbodiedAgent

# One actuator emulator: it consumes the living room's TurnLightOn.
BODY = Description(entity_id="my-spade-va", entity_type="Agent", components=[Component(
    "MyLightEmulator", [Entry("ACTUATOR", "ACTION FEEDBACK", {"Feedback": "yes"})],
    [Entry("ACTUATOR", "TurnLightOn", {"Light": "yes", "Room": "living"})])])


class LightAgent(EmbodiedAgent):
    async def on_percept(self, event):  # sensor data, events, Binding reports
        print("percept:", type(event).__name__)


async def main(evatar_port: int, xmpp_port: int) -> None:
    agent = LightAgent("light@127.0.0.1", "light-password", port=xmpp_port)
    body = agent.embody(Body(BODY, [("127.0.0.1", evatar_port)], pairing="home",
                             credential="home-va-secret"))
    await agent.start()  # joins the pairing; raises if EVATAR refuses
    await body.wait_bound()
    feedback = await body.act("MyLightEmulator", "TurnLightOn", {"Light": "yes", "Room": "living"})
    print("the living-room light is", feedback.param("Light"))
    await agent.stop()  # leaves the pairing, then XMPP


asyncio.run(main(int(sys.argv[1]), int(sys.argv[2]) if len(sys.argv) > 2 else 5222))

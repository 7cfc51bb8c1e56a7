"""The LEGO robots' coordination (docs/scenarios.md, scenario 1) with SPADE
agents: a coordinator (no body) and two robot VAs, each embodied through
EVATAR (evatar.spade) in its robot's pairing with lego_va.xml. The agents
talk only in FIPA-ACL messages over XMPP, each kind matched by a SPADE
Template on its metadata (``performative``, ``ontology``); EVATAR carries
only the bodies' signals.

    coordinator -> robot   request  explore {lanes, xs}    robot: agree, then inform anchors
    coordinator -> robot   inform   lexicon [...]          robot: inform adopted <digest>
    coordinator -> robot   request  pick-place {word,zone} robot: agree, then inform placed
                                                           (or failure, or refuse)
    coordinator -> robot   inform   done {...}
    robot -> coordinator   inform   ready {pose}           once its body is bound

SPADE delivers a message between agents of one process through its
container, past the XMPP server: so the coordinator runs in a process of
its own (``coordinator`` below) and every message between it and a robot
crosses the server. Each agent counts what reached it through its XMPP
client (``xmpp_received``).

    python robots_spade.py coordinator XMPP_PORT
        prints COORDINATOR_READY, then DONE <summary JSON> when every ball is placed
    python robots_spade.py run EVATAR_PORT XMPP_PORT VA_CREDENTIAL [PAIRING_PREFIX]
        starts the coordinator's process and the two robot VAs (pairings robot1, robot2
        of ``scripts/sim-node.sh start robots``), prints the summary, exits
"""

from __future__ import annotations

import asyncio
import collections
import json
import logging
import os
import subprocess
import sys
from typing import Any, Dict, List, Optional, Sequence, Tuple

from spade.agent import Agent
from spade.behaviour import CyclicBehaviour
from spade.message import Message
from spade.template import Template

from evatar import EvatarError, Signal
from evatar.spade import Body, EmbodiedAgent, reason

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import lexicon as lx  # noqa: E402

LEGO_VA = os.path.join(HERE, "..", "..", "..", "..", "apps", "bil", "priv", "examples",
                       "lego_va.xml")
LOG = logging.getLogger("robots_spade")
HOST = "127.0.0.1"
COORDINATOR = "coordinator@" + HOST
#: The ontologies: the arena's tasks, and the lexicon.
ARENA, LEXICON = "lego-arena", "lego-lexicon"
#: The task: the zone each colour goes to, and where the zones are (docs/avatars.md 3.1).
TARGETS = {"red": "se", "green": "nw", "blue": "n"}
ZONES = {"nw": (250, 1250), "n": (1000, 1300), "se": (1750, 250)}
ARENA_SIZE = (2000, 1500)
CLAW_MM, STANDOFF_MM, MAX_TRIES, MAX_DETOURS, ROUNDS = 110, 170, 4, 3, 3
#: Turns (degrees) that sweep the claw 90 degrees left, then right, in steps
#: small enough for the light sensor to see a ball anywhere on the bumper's front.
SCAN = [10] * 9 + [-100] + [-10] * 8


def acl(to: str, performative: str, ontology: str, content: Dict[str, Any]) -> Message:
    msg = Message(to=to, body=json.dumps(content))
    msg.set_metadata("performative", performative)
    msg.set_metadata("ontology", ontology)
    msg.set_metadata("language", "json")
    return msg


def template(performative: str, ontology: str) -> Template:
    return Template(metadata={"performative": performative, "ontology": ontology})


def bare(jid: Any) -> str:
    return str(jid).split("/")[0]


class Talker:
    """Counts the ACL messages that reached the agent through its XMPP
    client (SPADE's handler of the XMPP stream), by performative."""

    def _message_received(self, msg: Any) -> Any:
        counts = self.__dict__.setdefault("xmpp_received", collections.Counter())
        counts[str(Message.from_node(msg).get_metadata("performative"))] += 1
        return super()._message_received(msg)  # type: ignore[misc]


# --------------------------------------------------------------- coordinator


class Coordinator(Talker, Agent):
    """Sends the robots to explore, builds and distributes the lexicon,
    then commands one ball at a time until every ball is placed."""

    def __init__(self, jid: str, password: str, robots: Sequence[str], **kw: Any) -> None:
        super().__init__(jid, password, **kw)
        self.robots = list(robots)
        self.poses: Dict[str, Any] = {}
        self.reports: Dict[str, List[Dict[str, object]]] = {}
        self.round = 0
        self.lexicon: List[Dict[str, object]] = []
        self.acks: Dict[str, str] = {}
        self.placed: Dict[str, Dict[str, Any]] = {}
        self.given_up: List[str] = []
        self.attempts: Dict[str, List[str]] = collections.defaultdict(list)
        self.handled: collections.Counter = collections.Counter()
        self.done: "asyncio.Future[Dict[str, Any]]" = asyncio.get_event_loop().create_future()

    async def setup(self) -> None:
        self.add_behaviour(_Heard(self._arena), template("inform", ARENA))
        self.add_behaviour(_Heard(self._adopted), template("inform", LEXICON))
        self.add_behaviour(_Heard(self._agreed), template("agree", ARENA))
        self.add_behaviour(_Heard(self._failed),
                           template("failure", ARENA) | template("refuse", ARENA))

    async def _arena(self, b: CyclicBehaviour, sender: str, c: Dict[str, Any]) -> None:
        if "ready" in c:
            self.poses[sender] = c["ready"]
            if set(self.poses) == set(self.robots) and self.round == 0:
                await self._explore(b)
        elif "anchors" in c:
            self.reports[sender], self.poses[sender] = c["anchors"], c["pose"]
            if set(self.reports) == set(self.robots):
                await self._agree_lexicon(b)
        elif "placed" in c:
            self.placed[c["placed"]] = {"zone": c["zone"], "by": sender, "at": c["at"]}
            await self._next(b)

    async def _agreed(self, b: CyclicBehaviour, sender: str, c: Dict[str, Any]) -> None:
        pass  # the robot took the order on; its result is what moves things on

    async def _failed(self, b: CyclicBehaviour, sender: str, c: Dict[str, Any]) -> None:
        await self._next(b)

    async def _adopted(self, b: CyclicBehaviour, sender: str, c: Dict[str, Any]) -> None:
        self.acks[sender] = c["adopted"]
        if all(self.acks.get(r) == lx.digest(self.lexicon) for r in self.robots):
            await self._next(b)

    async def _explore(self, b: CyclicBehaviour) -> None:
        """Southern lanes to the robot furthest south; they swap every round."""
        by_y = sorted(self.robots, key=lambda r: (self.poses.get(r) or [0, 0])[1])
        if self.round % 2:
            by_y.reverse()
        self.round += 1
        self.reports = {}
        xs = [150, ARENA_SIZE[0] - 150]
        for robot, ys in zip(by_y, lx.share(lx.lanes(ARENA_SIZE[1]), len(by_y))):
            await b.send(acl(robot, "request", ARENA, {"action": "explore", "lanes": ys, "xs": xs}))

    async def _agree_lexicon(self, b: CyclicBehaviour) -> None:
        lexicon = lx.build_lexicon(self.reports)
        seen = {e["colour"] for e in lexicon}
        if not set(TARGETS) <= seen and self.round < ROUNDS:
            await self._explore(b)
            return
        self.given_up += ["%s (never seen)" % c for c in sorted(set(TARGETS) - seen)]
        self.lexicon, self.acks = lexicon, {}
        for robot in self.robots:
            await b.send(acl(robot, "inform", LEXICON, {"lexicon": lexicon}))

    async def _next(self, b: CyclicBehaviour) -> None:
        """The first ball by word that has a target and is neither placed
        nor given up; the robot that anchored it goes, else the other."""
        for e in self.lexicon:
            word, colour = str(e["word"]), str(e["colour"])
            if colour not in TARGETS or word in self.placed or word in self.given_up:
                continue
            names: Dict[str, str] = e["names"]  # type: ignore[assignment]
            order = sorted(self.robots, key=lambda r: r not in names)
            left = [r for r in order if r not in self.attempts[word]]
            if not left:
                self.given_up.append(word)
                continue
            self.attempts[word].append(left[0])
            zone = TARGETS[colour]
            await b.send(acl(left[0], "request", ARENA,
                             {"action": "pick-place", "word": word, "zone": zone,
                              "at": ZONES[zone]}))
            return
        summary = {"lexicon": self.lexicon, "placed": self.placed, "given_up": self.given_up,
                   "rounds": self.round, "orders": sum(map(len, self.attempts.values()))}
        for robot in self.robots:
            await b.send(acl(robot, "inform", ARENA, {"done": summary}))
        summary["handled"] = dict(self.handled)
        summary["xmpp_received"] = dict(self.__dict__.get("xmpp_received", {}))
        if not self.done.done():
            self.done.set_result(summary)


class _Heard(CyclicBehaviour):
    """One kind of message (the behaviour's template): ``handle(self,
    sender, content)``. Messages from strangers are ignored."""

    def __init__(self, handle: Any) -> None:
        super().__init__()
        self.handle = handle

    async def run(self) -> None:
        msg = await self.receive(timeout=60)
        if msg is None:
            return
        sender = bare(msg.sender)
        known = getattr(self.agent, "robots", None) or [COORDINATOR]
        if sender not in known:
            return
        self.agent.handled[msg.get_metadata("performative")] += 1
        LOG.info("%s <- %s %s %s", self.agent.jid.user, sender.split("@")[0],
                 msg.get_metadata("performative"), msg.body[:120])
        await self.handle(self, sender, json.loads(msg.body))


# --------------------------------------------------------------- robot VAs


class Robot(Talker, EmbodiedAgent):
    """A robot VA: sweeps the lanes it is given, anchoring what its light
    sensor sees; adopts the lexicon; picks and places the balls it is told
    to. Its actions are requests to its body (``await body.act``)."""

    def __init__(self, jid: str, password: str, prefix: str, **kw: Any) -> None:
        super().__init__(jid, password, **kw)
        self.anchors = lx.Anchors(prefix)
        self.lexicon: Optional[List[Dict[str, object]]] = None
        self.pose: Optional[List[float]] = None
        self.placed: List[Dict[str, Any]] = []
        self.handled: collections.Counter = collections.Counter()
        self.finished: "asyncio.Future[Dict[str, Any]]" = asyncio.get_event_loop().create_future()

    async def setup(self) -> None:
        self.add_behaviour(_Heard(self._order), template("request", ARENA))
        self.add_behaviour(_Heard(self._lexicon), template("inform", LEXICON))
        self.add_behaviour(_Heard(self._done), template("inform", ARENA))

    async def on_percept(self, event: Any) -> None:
        if (isinstance(event, Signal) and event.context == "SensorData"
                and event.type == "ColourApproximation" and lx.is_object(event.param("Colour"))):
            self.anchors.perceive(str(event.param("Colour")),
                                  (float(event.param("X") or 0), float(event.param("Y") or 0)),
                                  event.timestamp)

    # ------------------------------------------------------------ messages

    async def report_ready(self) -> None:
        await self.behave("Stop", {})
        b = next(x for x in self.behaviours if isinstance(x, _Heard))
        await b.send(acl(COORDINATOR, "inform", ARENA, {"ready": self.pose}))
        LOG.info("%s: ready at %s", self.jid.user, self.pose)

    async def _order(self, b: CyclicBehaviour, sender: str, c: Dict[str, Any]) -> None:
        action = c.get("action")
        if action == "explore":
            await b.send(acl(sender, "agree", ARENA, {"agree": action}))
            await self.explore(c["lanes"], c["xs"])
            await b.send(acl(sender, "inform", ARENA,
                             {"anchors": self.anchors.describe(), "pose": self.pose}))
        elif action == "pick-place" and self.target(c["word"]) is not None:
            await b.send(acl(sender, "agree", ARENA, {"agree": action, "word": c["word"]}))
            why = await self.pick_place(c["word"], c["at"])
            if why is None:
                await b.send(acl(sender, "inform", ARENA, {"placed": c["word"], "zone": c["zone"],
                                                           "at": self.placed[-1]["at"]}))
            else:
                await b.send(acl(sender, "failure", ARENA, {"failed": c["word"], "why": why}))
        else:
            await b.send(acl(sender, "refuse", ARENA, {"refused": c, "why": "unknown word"}))

    async def _lexicon(self, b: CyclicBehaviour, sender: str, c: Dict[str, Any]) -> None:
        self.lexicon = c["lexicon"]
        await b.send(acl(sender, "inform", LEXICON, {"adopted": lx.digest(c["lexicon"])}))

    async def _done(self, b: CyclicBehaviour, sender: str, c: Dict[str, Any]) -> None:
        if "done" in c and not self.finished.done():
            self.finished.set_result(c["done"])

    # ------------------------------------------------------------- the body

    async def behave(self, service: str, params: Dict[str, Any]) -> Signal:
        fb = await self.body.act(service + "BehaviourEmulator", service,
                                 {k: str(v) for k, v in params.items()})
        LOG.debug("%s: %s %s -> %s", self.jid.user, service, params, fb.body.parameters)
        if fb.param("X") is not None and fb.param("Heading") is not None:
            self.pose = [float(fb.param("X")), float(fb.param("Y")), float(fb.param("Heading"))]
        return fb

    async def goto(self, at: Sequence[float], heading: Optional[float] = None) -> str:
        params = {"X": round(at[0]), "Y": round(at[1])}
        if heading is not None:
            params["Heading"] = round(heading)
        return str((await self.behave("GoTo", params)).param("Result"))

    async def look(self) -> Optional[Tuple[str, Tuple[float, float]]]:
        """A light reading at the claw point, then turns across what the
        bumper touched; the ball seen (anchored), or None."""
        for turn in [0] + SCAN:
            if turn:
                await self.behave("Rotate", {"Angle": turn})
            fb = await self.body.act("LightSensorEmulator", "ReadLight", {})
            colour = fb.param("Colour")
            if lx.is_object(colour):
                at = (float(fb.param("X") or 0), float(fb.param("Y") or 0))
                self.anchors.perceive(str(colour), at, fb.timestamp)
                return str(colour), at
        return None

    async def go_round(self) -> None:
        """Back, left, ahead: round whatever is in the way."""
        await self.behave("Forward", {"Distance": "-0.12"})
        await self.behave("Rotate", {"Angle": 90})
        await self.behave("Forward", {"Distance": "0.25"})

    async def explore(self, ys: List[int], xs: Sequence[int]) -> None:
        for point in lx.waypoints(self.pose, ys, xs):
            for _ in range(MAX_DETOURS):
                if await self.goto(point) != "contact":
                    break
                await self.look()
                await self.go_round()

    def target(self, word: str) -> Optional[Tuple[str, Sequence[float]]]:
        """The ball's colour and where the VA believes it is: its own
        anchor, else the lexicon's place."""
        e = next((e for e in self.lexicon or [] if e["word"] == word), None)
        if e is None:
            return None
        mine = self.anchors.lookup(e["names"].get(str(self.jid.bare), ""))  # type: ignore[union-attr]
        return str(e["colour"]), (mine or e)["at"]  # type: ignore[return-value]

    async def pick_place(self, word: str, zone_at: Sequence[float]) -> Optional[str]:
        """Stand off facing the ball, move in until the bumper touches,
        check its colour, grab, carry, release. A failed try goes round
        and comes again from another side. None, or why it failed."""
        colour, ball = self.target(word)  # type: ignore[misc]
        why = "no try"
        try:
            for _ in range(MAX_TRIES):
                stand = lx.placement(self.pose, ball, STANDOFF_MM)
                if await self.goto(stand, lx.bearing(stand, ball)) != "contact":
                    await self.behave("Forward", {"Distance": "0.12", "Speed": "0.08"})
                seen = await self.look()
                if seen is None or seen[0] != colour:
                    why = "no ball at the claw" if seen is None else "the %s ball in the way" % seen[0]
                    await self.go_round()
                    continue
                ball = seen[1]
                grabbed = await self.behave("Grab", {})
                if grabbed.param("Holding") != "yes" or grabbed.param("Colour") != colour:
                    why = "the claw closed on %s" % (grabbed.param("Colour") or "nothing")
                    if grabbed.param("Holding") == "yes":
                        await self.behave("Release", {})
                    await self.go_round()
                    continue
                for _ in range(MAX_DETOURS):
                    result = await self.goto(lx.placement(self.pose, zone_at, CLAW_MM))
                    if result == "done":
                        break
                    await self.go_round()
                else:
                    return "could not reach the zone"
                put = await self.behave("Release", {})
                at = (float(put.param("BallX") or 0), float(put.param("BallY") or 0))
                symbol = next((e["names"].get(str(self.jid.bare)) for e in self.lexicon or []
                               if e["word"] == word), None)
                if symbol:
                    self.anchors.moved(str(symbol), at, put.timestamp)
                self.placed.append({"word": word, "at": [round(at[0]), round(at[1])]})
                await self.behave("Forward", {"Distance": "-0.2"})
                return None
        except EvatarError as e:  # an action refused: the coordinator hears why
            return "%s: %s" % (reason(e), e)
        return why


async def start_robots(evatar_port: int, xmpp_port: int, credential: str,
                       prefix: str = "robot") -> List[Robot]:
    """The two robot VAs, embodied and bound, each having told the
    coordinator it is ready."""
    robots = []
    for n in (1, 2):
        r = Robot("%s%d@%s" % (prefix, n, HOST), "robot-xmpp", "r%02d" % n, port=xmpp_port)
        r.embody(Body(LEGO_VA, [(HOST, evatar_port)], pairing="%s%d" % (prefix, n),
                      credential=credential, entity_id="golem-lego-va-%02d" % n))
        await r.start()
        LOG.info("%s joined %s%d", r.jid.user, prefix, n)
        await r.body.wait_bound(timeout=30)
        LOG.info("%s bound", r.jid.user)
        robots.append(r)
    for r in robots:
        await r.report_ready()
    return robots


async def coordinator(xmpp_port: int, prefix: str = "robot") -> None:
    c = Coordinator(COORDINATOR, "coordinator-xmpp",
                    ["%s%d@%s" % (prefix, n, HOST) for n in (1, 2)], port=xmpp_port)
    await c.start()
    print("COORDINATOR_READY", flush=True)
    summary = await c.done
    print("DONE", json.dumps(summary), flush=True)
    await c.stop()


async def run(evatar_port: int, xmpp_port: int, credential: str, prefix: str) -> None:
    proc = subprocess.Popen([sys.executable, os.path.abspath(__file__), "coordinator",
                             str(xmpp_port), prefix], stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    loop = asyncio.get_running_loop()
    robots: List[Robot] = []
    try:
        line = await loop.run_in_executor(None, proc.stdout.readline)
        if line.strip() != "COORDINATOR_READY":
            raise SystemExit("the coordinator did not start: %r" % line)
        robots = await start_robots(evatar_port, xmpp_port, credential, prefix)
        summary = await asyncio.wait_for(asyncio.gather(*(r.finished for r in robots)), 600)
        print(json.dumps(summary[0], indent=1))
        print((await loop.run_in_executor(None, proc.stdout.read)).strip())
    finally:
        for r in robots:
            await r.stop()
        if proc.poll() is None:
            proc.kill()
        proc.wait()


if __name__ == "__main__":
    logging.basicConfig(level="ERROR", stream=sys.stderr, format="%(name)s: %(message)s")
    LOG.setLevel(os.environ.get("ROBOTS_LOG", "WARNING"))
    if sys.argv[1:2] == ["coordinator"]:
        asyncio.run(coordinator(int(sys.argv[2]), *sys.argv[3:4]))
    elif sys.argv[1:2] == ["run"]:
        asyncio.run(run(int(sys.argv[2]), int(sys.argv[3]), sys.argv[4],
                        sys.argv[5] if len(sys.argv) > 5 else "robot"))
    else:
        sys.exit(__doc__)

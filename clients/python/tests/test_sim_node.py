"""scripts/sim-node.sh, the way Python and Java users reach avatar_sim
without Erlang: it starts a node with the simulated home (with a script
chosen here) or the LEGO robots; a VA joins; the failure hooks (mute,
detach, disconnect) are used from the shell and their effect is seen by the
VA. Also: docs/avatars.md section 7's tables are the descriptions the
simulations send."""

from __future__ import annotations

import asyncio
import os
import re
import stat
import subprocess
import sys
from pathlib import Path
from typing import Dict, Iterator, List, Tuple

import pytest

from evatar import (ActuatorEmulator, Binding, Client, Entry, NotBoundError, SensorEmulator,
                    describe)
from evatar.bil import parse_description

from conftest import REPO, Node, run

SIM = REPO / "scripts" / "sim-node.sh"
EXAMPLES = REPO / "apps" / "bil" / "priv" / "examples"


def sim(control: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([str(SIM), "--dir", str(control)] + list(args), cwd=str(REPO),
                          capture_output=True, text=True, timeout=120)


def start(tmp: Path, *args: str) -> Tuple[Node, Path]:
    control = tmp / "control"
    node = Node("sim-node.sh", ["--dir", str(control), "start"] + list(args)
                + ["--port", "0", "--va-credential", "va-sim", "--stop-on-eof"])
    return node, control


def provider(b: Binding, consumer: str, type: str) -> str:
    return next((r.provider_component for r in b.bound
                 if r.consumer_component == consumer and r.type == type), "")


def listening_addresses(pid: int) -> List[str]:
    """The local addresses of the TCP sockets process ``pid`` listens on."""
    inodes = set()
    for fd in os.listdir("/proc/%d/fd" % pid):
        try:
            target = os.readlink("/proc/%d/fd/%s" % (pid, fd))
        except OSError:
            continue
        m = re.match(r"socket:\[(\d+)\]", target)
        if m:
            inodes.add(m.group(1))
    out = []
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        with open(table) as f:
            for line in f.readlines()[1:]:
                cols = line.split()
                if cols[3] == "0A" and cols[9] in inodes:
                    out.append(cols[1])
    return out


@pytest.fixture
def home(tmp_path: Path) -> Iterator[Tuple[Node, Path]]:
    script = tmp_path / "evening.txt"
    script.write_text("# the resident walks into the kitchen a minute after the start\n"
                      "17:56  resident  go  kitchen\n")
    node, control = start(tmp_path, "home", "--script", str(script), "--speed", "60",
                          "--feedback-timeout", "2000")
    yield node, control
    node.stop()


def test_home_failure_hooks_from_the_shell(home: Tuple[Node, Path]) -> None:
    node, control = home
    assert "EVATAR_PAIRING=home" in node.lines and "EVATAR_VA_CREDENTIAL=va-sim" in node.lines
    # Safe by default: the control directory is private, and the node's
    # only TCP listener is the bridge on 127.0.0.1.
    assert stat.S_IMODE(os.stat(control).st_mode) == 0o700
    assert listening_addresses(node.proc.pid) == ["0100007F:%04X" % node.port]

    async def main() -> None:
        va = Client([("127.0.0.1", node.port)], pairing="home", role="agent",
                    entity_id="golem-home-va-01", credential="va-sim")
        await va.connect()
        await va.describe((EXAMPLES / "smart_home_va.xml").read_bytes())
        b = await va.wait_binding(
            lambda b: provider(b, "LivingLightEmulator01", "TurnLightOn") == "LivingLightSwitch01"
            and provider(b, "KitchenLightEmulator01", "TurnLightOn") == "KitchenLightSwitch01",
            timeout=30)
        assert "easy-home-01" in b.entities
        # The script chosen on the command line runs: the resident's walk
        # into the kitchen is seen by the kitchen's camera.
        motion = await va.next_signal(60, lambda s: s.receiver == "KitchenMotionEmulator01")
        assert (motion.type, motion.param("Motion"), motion.param("Room")) == (
            "MotionDetected", "yes", "kitchen")

        def turn_on() -> "asyncio.Future":
            return asyncio.ensure_future(va.request(
                sender="LivingLightEmulator01", receiver="LivingLightSwitch01",
                category="ACTUATOR", type="TurnLightOn",
                parameters={"Light": "yes", "Room": "living"}, timeout=30))

        # mute: the switch swallows the request; EVATAR's feedback timeout
        # answers for it.
        r = sim(control, "mute", "LivingLightSwitch01")
        assert r.returncode == 0, r.stderr
        # Every command prints something: the hooks a confirmation.
        assert r.stdout.startswith("ok muted LivingLightSwitch01"), r.stdout
        fb = await turn_on()
        assert fb.is_evatar_timeout
        assert "muted=LivingLightSwitch01" in sim(control, "links").stdout
        r = sim(control, "unmute", "LivingLightSwitch01")
        assert r.returncode == 0 and r.stdout == "ok unmuted LivingLightSwitch01\n", r
        fb = await turn_on()
        assert not fb.is_evatar_timeout and fb.param("Light") == "on"

        # detach: the kitchen's switch leaves; the report says the
        # kitchen emulator's entries are unbound.
        r = sim(control, "detach", "KitchenLightSwitch01")
        assert r.returncode == 0 and r.stdout == "ok detached KitchenLightSwitch01\n", r
        b = await va.wait_binding(lambda b: any(
            u.consumer_component == "KitchenLightEmulator01" and u.type == "TurnLightOn"
            for u in b.unbound), timeout=30)
        assert provider(b, "KitchenLightEmulator01", "TurnLightOn") == ""
        assert provider(b, "LivingLightEmulator01", "TurnLightOn") == "LivingLightSwitch01"
        assert sim(control, "attach", "KitchenLightSwitch01").returncode == 0
        await va.wait_binding(lambda b: provider(b, "KitchenLightEmulator01", "TurnLightOn")
                              == "KitchenLightSwitch01", timeout=30)

        # disconnect: the gateway's link drops; EVATAR unbinds the home.
        assert sim(control, "disconnect", "easy-home-01").returncode == 0
        await va.wait_binding(lambda b: "easy-home-01" not in b.entities, timeout=30)
        assert "LINK easy-home-01 home away" in sim(control, "links").stdout
        assert sim(control, "reconnect", "easy-home-01").returncode == 0
        await va.wait_binding(lambda b: provider(b, "LivingLightEmulator01", "TurnLightOn")
                              == "LivingLightSwitch01", timeout=30)
        await va.close()
    run(main())

    # Refused commands: a clear error, a non-zero status.
    r = sim(control, "mute", "NoSuchDevice")
    assert r.returncode == 1 and "NoSuchDevice" in r.stderr and "unknown_component" in r.stderr
    r = sim(control, "mute", "a;b")
    assert r.returncode == 2 and "bad argument" in r.stderr
    # stop: the node ends, and a command then finds nothing.
    r = sim(control, "stop")
    assert r.returncode == 0 and r.stdout == "ok stopped\n", r
    assert node.proc.wait(30) == 0
    r = sim(control, "links")
    assert r.returncode == 3 and "no simulated node" in r.stderr


def test_paused_start_night_watch_binding(tmp_path: Path) -> None:
    """--paused: no simulated time passes until `resume', so a VA binds
    before the first event; `time' shows it. A VA's own emulators are told
    bound or not by Binding.is_bound / unbound_for, not by the pairing's
    entities; the device's answers reach an actuator emulator through the
    row of its action even when the device's ACTION FEEDBACK entry is bound
    to another emulator, and `feedback=' binds that entry."""
    node, control = start(tmp_path, "home", "--script", "none", "--paused", "--speed", "60")
    try:
        r = sim(control, "time")
        assert r.returncode == 0 and r.stdout == "TIME 2024-11-15 17:55:00 paused speed=60\n", r
        r = sim(control, "outcome")
        assert r.returncode == 0 and r.stdout.startswith("no outcome yet"), r

        async def main() -> None:
            va = Client([("127.0.0.1", node.port)], pairing="home", role="agent",
                        entity_id="night-watch-va", credential="va-sim")
            socket = [Entry("ACTUATOR", "SwitchSocketOn", {"Appliance": "lamp", "Room": "bedroom"}),
                      Entry("ACTUATOR", "SwitchSocketOff", {"Appliance": "lamp", "Room": "bedroom"})]
            # The one whose feedback service matches the socket's Consumes entry.
            lamp = ActuatorEmulator(va, "LampEmulator", socket,
                                    feedback={"Feedback": "yes", "Device": "SocketSwitch",
                                              "Room": "bedroom"})
            # The default feedback service {"Feedback": "yes"}: no device's entry binds to it.
            plain = ActuatorEmulator(va, "PlainLampEmulator", socket)
            wrong = ActuatorEmulator(va, "AtticLampEmulator",
                                     [Entry("ACTUATOR", "SwitchSocketOn",
                                            {"Appliance": "lamp", "Room": "attic"})])
            motion = SensorEmulator(va, "BedroomMotion", "MotionDetected", {"Room": "bedroom"})
            await va.connect()
            d = await describe(va, [lamp, plain, wrong, motion], api_name="NIGHT WATCH")
            assert len(d.components) == 4
            b = await va.wait_binding(lambda b: b.is_bound("LampEmulator")
                                      and b.is_bound("BedroomMotion"), timeout=60)
            assert b.is_bound("PlainLampEmulator") and not b.is_bound("AtticLampEmulator")
            assert [(u.consumer_component, u.type, u.reason)
                    for u in b.unbound_for("night-watch-va")] == [
                ("AtticLampEmulator", "SwitchSocketOn", "ParametersMismatch")]
            fb_rows = [r for r in b.bound if r.consumer_component == "BedroomSocketSwitch01"
                       and r.type == "ACTION FEEDBACK"]
            assert [r.provider_component for r in fb_rows] == ["LampEmulator"]
            with pytest.raises(NotBoundError) as e:
                await wrong.act("SwitchSocketOn", {"Appliance": "lamp", "Room": "attic"})
            assert e.value.reason == "ParametersMismatch"
            assert "client.binding.unbound" in str(e.value)

            # Still paused: the VA joined and bound, no simulated time passed.
            assert sim(control, "time").stdout.startswith("TIME 2024-11-15 17:55:00 paused")
            r = sim(control, "resume")
            assert r.returncode == 0 and r.stdout == "ok clock running\n", r
            # Both emulators get the socket's answer, through their own rows.
            fb = await plain.act("SwitchSocketOn", {"Appliance": "lamp", "Room": "bedroom"},
                                 timeout=30)
            assert not fb.is_evatar_timeout and fb.param("Socket") == "on", fb
            assert fb.sender == "BedroomSocketSwitch01" and fb.timestamp > 0
            fb = await lamp.act("SwitchSocketOff", {"Appliance": "lamp", "Room": "bedroom"},
                                timeout=30)
            assert not fb.is_evatar_timeout and fb.param("Socket") == "off", fb
            await va.close()
        run(main())
        r = sim(control, "outcome")
        assert r.returncode == 0 and re.search(r"^LIGHT \d\d:\d\d bedroom on$", r.stdout,
                                               re.M), r
    finally:
        node.stop()


def test_robots_from_the_shell(tmp_path: Path) -> None:
    # The feedback timeout answers for the muted motor below: 2 s, not 5.
    node, control = start(tmp_path, "robots", "--feedback-timeout", "2000")
    try:
        assert [l for l in node.lines if l.startswith("EVATAR_PAIRING=")] == [
            "EVATAR_PAIRING=robot1", "EVATAR_PAIRING=robot2"]

        async def main() -> None:
            va = Client([("127.0.0.1", node.port)], pairing="robot1", role="agent",
                        entity_id="golem-lego-va-01", credential="va-sim")
            await va.connect()
            await va.describe((EXAMPLES / "lego_va.xml").read_bytes())
            await va.wait_binding(lambda b: provider(b, "ForwardBehaviourEmulator", "Forward")
                                  == "ForwardBehaviour", timeout=30)
            assert sim(control, "detach", "ForwardBehaviour").returncode == 0
            await va.wait_binding(lambda b: provider(b, "ForwardBehaviourEmulator", "Forward")
                                  == "" and "lego-nxt-01" in b.entities, timeout=30)
            assert sim(control, "mute", "MotorA").returncode == 0
            fb = await va.request(sender="MotorAEmulator", receiver="MotorA",
                                  category="ACTUATOR", type="Rotate",
                                  parameters={"Angle": "90"}, timeout=30)
            assert fb.is_evatar_timeout
            await va.close()
        run(main())
        links = sim(control, "links").stdout.splitlines()
        assert [l.split()[1:4] for l in links] == [["lego-nxt-01", "robot1", "connected"],
                                                  ["lego-nxt-02", "robot2", "connected"]]
        assert "ENTITIES lego-nxt-02" in sim(control, "entities", "robot2").stdout
        # The arena's truth: where each ball is, and who holds it.
        r = sim(control, "outcome")
        assert r.returncode == 0, r
        assert sorted(l.split()[1] for l in r.stdout.splitlines() if l.startswith("BALL ")) == [
            "blue", "green", "red"], r.stdout
    finally:
        node.stop()


# docs/avatars.md section 7 against the descriptions ------------------------

ENTRY = re.compile(r"^`([^`]+)` / `([^`]+)`(?:: (.*))?$")
PARAM = re.compile(r"^(\S+) `([^`]*)`$")


def doc_tables() -> Dict[str, List[Tuple[str, List[Entry], List[Entry]]]]:
    text = (REPO / "docs" / "avatars.md").read_text()
    section = text.split("## 7. What a VA's emulators need to bind to each device")[1]
    section = section.split("\n## ")[0]
    tables: Dict[str, List[Tuple[str, List[Entry], List[Entry]]]] = {}
    current = ""
    for line in section.splitlines():
        m = re.match(r"^#### (\S+) \(`([^`]+)`\)", line)
        if m:
            current = "%s %s" % m.groups()
            tables[current] = []
        elif current and line.startswith("| `"):
            cells = [c.strip() for c in line.strip("|").split(" | ")]
            tables[current].append((cells[0].strip("`"), entries(cells[1]), entries(cells[2])))
    return tables


def entries(cell: str) -> List[Entry]:
    if cell == "none":
        return []
    out = []
    for e in cell.split("<br>"):
        m = ENTRY.match(e)
        assert m, "not an entry: %r" % e
        params = []
        for p in (m.group(3).split(", ") if m.group(3) else []):
            pm = PARAM.match(p)
            assert pm, "not a parameter: %r" % p
            params.append((pm.group(1), pm.group(2)))
        out.append(Entry(m.group(1), m.group(2), params))
    return out


def test_avatars_doc_lists_every_device_as_described() -> None:
    tables = doc_tables()
    want = {}
    for file in ("lego_robot.xml", "smart_home.xml"):
        d = parse_description((EXAMPLES / file).read_bytes())
        want["%s %s" % (file, d.entity_id)] = [(c.id, c.services, c.consumes)
                                              for c in d.components]
    assert sorted(tables) == sorted(want)
    for k in want:
        assert tables[k] == want[k], k


def test_control_directory_must_be_private(tmp_path: Path) -> None:
    """A control directory others can enter is refused before anything
    starts: whoever can open the socket can drive the simulation."""
    shared = tmp_path / "shared"
    shared.mkdir()
    shared.chmod(0o777)
    r = sim(shared, "start", "home", "--port", "0")
    assert r.returncode == 2 and "not 700" in r.stderr
    assert not (shared / "node.sock").exists()


def test_port_in_use_is_a_clear_error(tmp_path: Path) -> None:
    import socket
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        r = sim(tmp_path / "c", "start", "home", "--port", str(taken.getsockname()[1]))
    assert r.returncode == 2 and "the port is in use" in r.stderr


def test_clients_md_step_6_runs_as_written(tmp_path: Path) -> None:
    """docs/clients.md step 6's VA, as written (only the port changed):
    it waits with Binding.is_bound for its own emulator, then switches the
    living-room light on."""
    text = (REPO / "docs" / "clients.md").read_text()
    step = text[text.index("### 6. The simulated home"):]
    code = step[step.index("```python\n") + len("```python\n"):]
    code = code[:code.index("```")]
    assert 'b.is_bound("LivingLightEmulator01")' in code
    node, _control = start(tmp_path, "home", "--script", "none", "--speed", "20")
    try:
        va = tmp_path / "step6.py"
        va.write_text(code.replace("7400", str(node.port)).replace('"va-secret"', '"va-sim"'))
        r = subprocess.run([os.environ.get("PYTHON", sys.executable), str(va)], cwd=str(REPO),
                           capture_output=True, text=True, timeout=120)
        assert r.returncode == 0 and r.stdout == "the living-room light is on\n", r
    finally:
        node.stop()

"""The SDK over real TLS: a node (scripts/test-node.sh with EVATAR_TLS_DIR)
with a TLS listener and one that requires client certificates, and
certificates made by scripts/gen-bridge-certs.sh. A full session, the
server checked by CA or by pinned fingerprint, and each refusal with the
error the application sees."""

from __future__ import annotations

import subprocess
from pathlib import Path
from typing import Iterator, Tuple

import pytest

from evatar import (Actuator, ActuatorEmulator, Binding, Client, ConnectError, Entry,
                    PinMismatch, Sensor, SensorEmulator, Tls, describe)

from conftest import REPO, Node, run

PAIRING = "secure:sec-va:sec-avatar"


def gen_certs(d: Path, *clients: str) -> Path:
    subprocess.run(["bash", str(REPO / "scripts" / "gen-bridge-certs.sh"), str(d), *clients],
                   check=True, capture_output=True,
                   env={"EVATAR_SERVER_HOSTS": "localhost 127.0.0.1", "PATH": "/usr/bin:/bin"})
    return d


@pytest.fixture(scope="module")
def certs(tmp_path_factory) -> Tuple[Path, Path]:  # type: ignore[no-untyped-def]
    base = tmp_path_factory.mktemp("tls")
    return gen_certs(base / "certs", "va", "av"), gen_certs(base / "rogue", "va")


@pytest.fixture(scope="module")
def tls_node(certs) -> Iterator[Node]:  # type: ignore[no-untyped-def]
    n = Node("test-node.sh", [PAIRING], env={"EVATAR_TLS_DIR": str(certs[0])})
    yield n
    n.stop()


def ep(node: Node, which: str) -> Tuple[str, int]:
    return ("localhost", node.ports[which])


def read(p: Path) -> str:
    return p.read_text().strip()


def client(node: Node, which: str, role: str, entity: str, tls: Tls) -> Client:
    cred = "sec-va" if role == "agent" else "sec-avatar"
    return Client([ep(node, which)], pairing="secure", role=role, entity_id=entity,
                  credential=cred, tls=tls)


def with_cert(d: Path, name: str, ca: Path) -> Tls:
    return Tls(cafile=str(ca / "ca.pem"), certfile=str(d / ("client-%s.pem" % name)),
               keyfile=str(d / ("client-%s.key" % name)))


def session(node: Node, which: str, va_tls: Tls, av_tls: Tls) -> None:
    """Hello, describe, bind, a request with its feedback, 50 sensor signals.
    The VA's id is per listener: a failed run leaves no entity behind for
    the next one."""
    async def main() -> None:
        va = client(node, which, "agent", "va-" + which, va_tls)
        light = ActuatorEmulator(va, "LightEmulator01",
                                 [Entry("ACTUATOR", "TurnLightOn", {"Light": "yes"})])
        motion = SensorEmulator(va, "MotionEmulator01", "MotionDetected")
        av = client(node, which, "avatar", "av-" + which, av_tls)
        act = Actuator(av, "HomeLightActuator01",
                       [Entry("ACTUATOR", "TurnLightOn", {"Light": "yes"})],
                       lambda s: {"Done": "yes"})
        sensor = Sensor(av, "MotionSensor", "MotionDetected")
        w = await va.connect()
        assert w.pairing == "secure" and len(w.session_id) == 32
        await av.connect()
        await describe(va, [light, motion])
        await describe(av, [act, sensor])
        b = await va.wait_binding(lambda b: any(r.provider_component == "HomeLightActuator01"
                                                for r in b.bound))
        assert isinstance(b, Binding)
        await av.wait_binding(lambda b: any(r.consumer_component == "MotionSensor"
                                            and r.provider_component == "MotionEmulator01"
                                            for r in b.bound))
        fb = await light.act("TurnLightOn", {"Light": "yes"}, timeout=5)
        assert fb.context == "Feedback" and fb.param("Done") == "yes"
        for i in range(50):
            await sensor.emit({"Motion": "yes", "N": str(i)})
        got = [await motion.reading(5) for _ in range(50)]
        assert [s.param("N") for s in got] == [str(i) for i in range(50)]
        await va.close()
        await av.close()
    run(main())


def connect_error(node: Node, which: str, tls: Tls) -> str:
    async def main() -> str:
        with pytest.raises(ConnectError) as e:
            await client(node, which, "agent", "va", tls).connect()
        [(_, why)] = e.value.failures
        return why
    return run(main())


def test_session_over_tls_with_ca(tls_node, certs) -> None:  # type: ignore[no-untyped-def]
    tls = Tls(cafile=str(certs[0] / "ca.pem"))
    session(tls_node, "EVATAR_TLS_PORT", tls, tls)


def test_session_with_client_certificates(tls_node, certs) -> None:  # type: ignore[no-untyped-def]
    good = certs[0]
    session(tls_node, "EVATAR_MTLS_PORT", with_cert(good, "va", good), with_cert(good, "av", good))


def test_pinned_server(tls_node, certs) -> None:  # type: ignore[no-untyped-def]
    pin = read(certs[0] / "server.sha256")
    pretty = ":".join(pin[i:i + 2].upper() for i in range(0, len(pin), 2))

    async def main() -> None:
        c = client(tls_node, "EVATAR_TLS_PORT", "avatar", "av-pinned", Tls(pin_sha256=pretty))
        await c.connect()
        await c.close()
    run(main())


def test_pin_mismatch(tls_node, certs) -> None:  # type: ignore[no-untyped-def]
    wrong = read(certs[1] / "server.sha256")
    why = connect_error(tls_node, "EVATAR_TLS_PORT", Tls(pin_sha256=wrong))
    assert why.startswith("PinMismatch:") and wrong in why and read(certs[0] / "server.sha256") in why


def test_untrusted_server(tls_node, certs) -> None:  # type: ignore[no-untyped-def]
    # A man in the middle with his own certificate looks the same.
    why = connect_error(tls_node, "EVATAR_TLS_PORT", Tls(cafile=str(certs[1] / "ca.pem")))
    assert "CERTIFICATE_VERIFY_FAILED" in why, why


def test_wrong_server_name(tls_node, certs) -> None:  # type: ignore[no-untyped-def]
    why = connect_error(tls_node, "EVATAR_TLS_PORT",
                        Tls(cafile=str(certs[0] / "ca.pem"), server_hostname="evatar.example"))
    assert "CERTIFICATE_VERIFY_FAILED" in why and "evatar.example" in why, why


def test_client_without_certificate(tls_node, certs) -> None:  # type: ignore[no-untyped-def]
    why = connect_error(tls_node, "EVATAR_MTLS_PORT", Tls(cafile=str(certs[0] / "ca.pem")))
    assert "CERTIFICATE_REQUIRED" in why, why


def test_client_with_untrusted_certificate(tls_node, certs) -> None:  # type: ignore[no-untyped-def]
    why = connect_error(tls_node, "EVATAR_MTLS_PORT", with_cert(certs[1], "va", certs[0]))
    assert "UNKNOWN_CA" in why, why

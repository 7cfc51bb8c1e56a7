"""The pure part of the LEGO robots' minds (docs/scenarios.md, scenario 1):
a robot VA's anchors (Coradeschi and Saffiotti: a symbol per perceived
object, tracked while seen near where it was, reacquired when its colour
turns up elsewhere after a while), the coordinator's lexicon built from the
robots' anchors (one shared word per object), and the geometry of lanes and
approaches. Plain values only, so they travel as JSON in ACL messages."""

from __future__ import annotations

import hashlib
import json
import math
from typing import Dict, List, Optional, Sequence, Tuple

Point = Tuple[float, float]

#: Sightings of one colour closer than this are the same object (a robot's anchors).
SAME_PLACE_MM = 250
#: An anchor not seen for this long (simulated ms) may have been moved.
STALE_MS = 20000
#: Reports of one colour further apart than this are different objects (the lexicon).
SAME_OBJECT_MM = 400
#: Colours of the arena itself: floor, zones, walls.
BACKGROUND = ("grey", "white", "black")


def is_object(colour: Optional[str]) -> bool:
    return bool(colour) and colour.lower() not in BACKGROUND


def distance(a: Sequence[float], b: Sequence[float]) -> float:
    return math.hypot(a[0] - b[0], a[1] - b[1])


class Anchors:
    """One robot VA's anchors; symbols start with ``prefix``."""

    def __init__(self, prefix: str) -> None:
        self.prefix = prefix
        self.anchors: List[Dict[str, object]] = []

    def perceive(self, colour: str, at: Point, time: int) -> Tuple[str, str]:
        """Anchors a sighting; returns (acquired|tracked|reacquired, symbol)."""
        same = sorted(((distance(a["at"], at), i) for i, a in enumerate(self.anchors)  # type: ignore[arg-type]
                       if str(a["colour"]).lower() == colour.lower()))
        if same and same[0][0] <= SAME_PLACE_MM:
            how, a = "tracked", self.anchors[same[0][1]]
        else:
            stale = [self.anchors[i] for _, i in same
                     if time - int(self.anchors[i]["last_seen"]) >= STALE_MS]  # type: ignore[call-overload]
            if stale:
                how, a = "reacquired", stale[0]
            else:
                a = {"symbol": "%s-obj%d" % (self.prefix, len(self.anchors) + 1),
                     "colour": colour, "seen": 0}
                self.anchors.append(a)
                how = "acquired"
        a.update(at=[round(at[0]), round(at[1])], last_seen=time,
                 seen=int(a["seen"]) + 1)  # type: ignore[call-overload]
        return how, str(a["symbol"])

    def moved(self, symbol: str, at: Point, time: int) -> None:
        """The VA carried the object itself: its anchor follows."""
        for a in self.anchors:
            if a["symbol"] == symbol:
                a.update(at=[round(at[0]), round(at[1])], last_seen=time)

    def lookup(self, symbol: str) -> Optional[Dict[str, object]]:
        return next((a for a in self.anchors if a["symbol"] == symbol), None)

    def describe(self) -> List[Dict[str, object]]:
        """What the VA tells others: symbol, colour, place."""
        return [{k: a[k] for k in ("symbol", "colour", "at")} for a in self.anchors]


def build_lexicon(reports: Dict[str, List[Dict[str, object]]]) -> List[Dict[str, object]]:
    """The lexicon from every robot's anchors: sightings of one colour
    close together (each robot once) are one object, named ``red-ball``
    (``red-ball-1``, ``-2``... when there are several), with its mean place
    and every robot's own symbol for it. Sorted by word; the same reports
    give the same lexicon whatever order they came in."""
    sightings = sorted((str(a["colour"]).lower(), tuple(a["at"]), robot, str(a["symbol"]))  # type: ignore[arg-type]
                       for robot, anchors in reports.items() for a in anchors)
    groups: List[List[Tuple[str, Tuple[float, float], str, str]]] = []
    for s in sightings:
        home = next((g for g in groups if g[0][0] == s[0] and distance(g[0][1], s[1])
                     <= SAME_OBJECT_MM and all(o[2] != s[2] for o in g)), None)
        if home is None:
            groups.append([s])
        else:
            home.append(s)
    lexicon = []
    for colour in sorted({g[0][0] for g in groups}):
        mine = [g for g in groups if g[0][0] == colour]
        for i, g in enumerate(mine, 1):
            word = "%s-ball" % colour if len(mine) == 1 else "%s-ball-%d" % (colour, i)
            lexicon.append({"word": word, "colour": colour,
                            "at": [round(sum(s[1][0] for s in g) / len(g)),
                                   round(sum(s[1][1] for s in g) / len(g))],
                            "names": {s[2]: s[3] for s in g}})
    return sorted(lexicon, key=lambda e: str(e["word"]))


def digest(lexicon: List[Dict[str, object]]) -> str:
    """What a robot sends back to say which lexicon it adopted."""
    return hashlib.sha256(json.dumps(lexicon, sort_keys=True).encode()).hexdigest()[:16]


def lanes(height: int, spacing: int = 200, margin: int = 150) -> List[int]:
    """Lane y values ``spacing`` apart: a bumper touches every ball within
    110 mm of its path."""
    return list(range(margin, height - margin + 1, spacing))


def share(items: List[int], n: int) -> List[List[int]]:
    """``items`` in ``n`` consecutive shares, as even as can be."""
    size, extra = divmod(len(items), n)
    out, i = [], 0
    for k in range(n):
        take = size + (1 if k < extra else 0)
        out.append(items[i:i + take])
        i += take
    return out


def waypoints(pose: Optional[Sequence[float]], ys: List[int], xs: Sequence[int]) -> List[Point]:
    """A serpentine sweep of lanes ``ys`` between ``xs``, starting at the
    lane and the end nearest the robot."""
    px, py = (pose[0], pose[1]) if pose else (xs[0], ys[0])
    ordered = sorted(ys)
    if abs(py - ordered[0]) > abs(py - ordered[-1]):
        ordered.reverse()
    ends = list(xs) if abs(px - xs[0]) <= abs(px - xs[1]) else [xs[1], xs[0]]
    out: List[Point] = []
    for y in ordered:
        out += [(ends[0], y), (ends[1], y)]
        ends.reverse()
    return out


def placement(pose: Optional[Sequence[float]], target: Sequence[float], short: float) -> Point:
    """Where the robot's centre stops to be ``short`` mm before ``target``
    coming from ``pose`` (the claw's 110 mm puts the claw on the target)."""
    if not pose:
        return (target[0], target[1])
    d = distance(pose, target)
    if d <= short:
        return (target[0], target[1])
    return (target[0] - short * (target[0] - pose[0]) / d,
            target[1] - short * (target[1] - pose[1]) / d)


def bearing(a: Sequence[float], b: Sequence[float]) -> float:
    return math.degrees(math.atan2(b[1] - a[1], b[0] - a[0])) % 360

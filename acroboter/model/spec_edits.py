"""A spec's TOML text with some of its entries replaced: the winches' limits, the path's waypoints and yaw.

The studies, the tools and the tests derive their cranes from the shipped specs this way: a case is a shipped spec
plus what it changes, written to a file a user could have written by hand (and could read in the run's folder).
Each edit refuses a text it cannot edit whole (no such entry, a winch without its cable line, an array it cannot
find the end of), rather than return it unchanged or half changed.
"""

from __future__ import annotations

import re
from collections.abc import Sequence

__all__ = ["with_path", "with_winch_limits"]


def with_winch_limits(text: str, upper: float, lower: float | None = None) -> str:
    """`text` with every winch actuator's limits set to [lower, upper] N (lower: the spec's own, else 0)."""
    blocks = re.split(r"(?=^\[\[actuators\]\])", text, flags=re.M)
    out, winches, placed = [], 0, 0
    for block in blocks:
        if block.startswith("[[actuators]]") and re.search(r'^kind\s*=\s*"winch_tension"', block, flags=re.M):
            winches += 1
            if re.search(r"^limits\s*=\s*\[[^\]\n]*(#.*)?$", block, flags=re.M):
                raise ValueError("a winch's limits = [...] spans lines: write it on one line to have it replaced")
            found = re.search(r"^limits\s*=\s*\[\s*([^,\]]+),", block, flags=re.M)
            low = float(lower) if lower is not None else (float(found.group(1)) if found else 0.0)
            block = re.sub(r"^limits\s*=.*(\n|\Z)", "", block, flags=re.M)
            line = f"limits = [{low!r}, {float(upper)!r}]\n"
            block, n = re.subn(r'^(cable\s*=\s*"[^"]*".*?)(\n|\Z)', lambda m, line=line: f"{m.group(1)}\n{line}",
                               block, count=1, flags=re.M)
            placed += n
        out.append(block)
    if not winches:
        raise ValueError('no [[actuators]] of kind "winch_tension" to give limits to')
    if placed != winches:
        raise ValueError(f'{winches - placed} of {winches} winch actuators have no cable = "..." line to put the '
                         "limits after")
    return "".join(out)


def _array_end(text: str, start: int) -> int:
    """The index just past the `]` that closes the array whose `[` is at `start` (comments and strings aside: a
    spec's coordinates are numbers)."""
    depth = 0
    for k in range(start, len(text)):
        depth += {"[": 1, "]": -1}.get(text[k], 0)
        if depth == 0:
            return k + 1
    raise ValueError("waypoints = [ ... has no closing ]")


def with_path(text: str, waypoints: Sequence[Sequence[float]], yaw_deg: float | None = None) -> str:
    """`text` with the path's waypoints (m, relative to the start) and, if given, its yaw turn (°) replaced."""
    points = ", ".join("[" + ", ".join(repr(float(c)) for c in p) + "]" for p in waypoints)
    found = re.search(r"^waypoints\s*=\s*(\[)", text, flags=re.M)
    if found is None:
        raise ValueError("no waypoints = [...] to replace")
    text = text[:found.start()] + f"waypoints = [{points}]" + text[_array_end(text, found.start(1)):]
    if yaw_deg is not None:
        text, turned = re.subn(r"^yaw_deg\s*=.*$", f"yaw_deg = {float(yaw_deg)!r}", text, count=1, flags=re.M)
        if not turned:
            raise ValueError("no yaw_deg = ... to replace")
    return text

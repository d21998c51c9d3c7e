"""A spec's TOML text with some of its entries replaced: the winches' limits, the path's waypoints and yaw.

The studies, the tools and the tests derive their cranes from the shipped specs this way: a case is a shipped spec
plus what it changes, written to a file a user could have written by hand (and could read in the run's folder).
Each edit refuses a text that has no such entry to replace, rather than return it unchanged.
"""

from __future__ import annotations

import re
from collections.abc import Sequence

__all__ = ["with_path", "with_winch_limits"]


def with_winch_limits(text: str, upper: float, lower: float | None = None) -> str:
    """`text` with every winch actuator's limits set to [lower, upper] N (lower: the spec's own, else 0)."""
    blocks = re.split(r"(?=^\[\[actuators\]\])", text, flags=re.M)
    out, winches = [], 0
    for block in blocks:
        if block.startswith("[[actuators]]") and re.search(r'^kind\s*=\s*"winch_tension"', block, flags=re.M):
            found = re.search(r"^limits\s*=\s*\[\s*([^,\]]+),", block, flags=re.M)
            low = float(lower) if lower is not None else (float(found.group(1)) if found else 0.0)
            block = re.sub(r"^limits\s*=.*\n", "", block, flags=re.M)
            block, placed = re.subn(r'^(cable\s*=\s*"[^"]*".*\n)', rf"\1limits = [{low!r}, {float(upper)!r}]\n",
                                    block, count=1, flags=re.M)
            winches += placed
        out.append(block)
    if not winches:
        raise ValueError("no [[actuators]] of kind \"winch_tension\" with a cable = \"...\" line to give limits to")
    return "".join(out)


def with_path(text: str, waypoints: Sequence[Sequence[float]], yaw_deg: float | None = None) -> str:
    """`text` with the path's waypoints (m, relative to the start) and, if given, its yaw turn (°) replaced."""
    points = ", ".join("[" + ", ".join(repr(float(c)) for c in p) + "]" for p in waypoints)
    text, found = re.subn(r"^waypoints\s*=\s*\[.*?\n\]", f"waypoints = [{points}]", text, count=1,
                          flags=re.S | re.M)
    if not found:
        raise ValueError("no multi-line waypoints = [...] to replace")
    if yaw_deg is not None:
        text, turned = re.subn(r"^yaw_deg\s*=.*$", f"yaw_deg = {float(yaw_deg)!r}", text, count=1, flags=re.M)
        if not turned:
            raise ValueError("no yaw_deg = ... to replace")
    return text

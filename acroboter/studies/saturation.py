"""Saturation strategies side by side (docs/saturation.md): the bounded least squares ("qp") against saturation as
underactuation, on cranes whose winch limits sit just below what their path needs.

A scenario is a shipped spec with its winches' upper limit changed (the TOML text, so that the library is the
shipped one: limits are read at run time). Each run is measured from its records alone:

- position error (max, rms, mm), yaw error (max, deg), tilt (max, deg);
- time on limits: the control periods with any input held at a limit (limit_state ≠ 0), s; the number of
  episodes (a run of such periods), a chatter count;
- recovery: after the last period on a limit, the time until the position error is back below
  RECOVERED_MM and stays there to the end (None: it never is);
- the worst excursion of any input beyond its limits (must be 0: never a silent clip, never beyond), and
  whether every input and state stayed finite.
"""

from __future__ import annotations

import re
import time
from dataclasses import asdict, dataclass

import numpy as np

RECOVERED_MM = 1.0  # position error below which a run has recovered (the unsaturated runs track to 0.06 mm)
STRATEGIES = ("qp", "underactuation")


@dataclass(frozen=True)
class Scenario:
    name: str  # a label for the tables
    spec: str  # a shipped spec's name (acroboter.example_spec)
    upper: float  # N, every winch's upper limit
    lower: float | None = None  # N, every winch's lower limit (None: the spec's)
    note: str = ""


# The two scenarios nobody tuned for: the default crane just below its peak need (26.91 N at
# t = 25.14 s; static 26.75 N), and the four-cable crane with a tight upper limit (its tensions span
# 19.98..20.30 N on the path, the static share 20.07 N).
SCENARIOS = (
    Scenario("default crane, max 26.9 N", "acroboter", 26.9, 0.0, "peak need 26.91 N"),
    Scenario("default crane, max 27.0 N", "acroboter", 27.0, 0.0, "peak need 27.06 N at the column's turn"),
    Scenario("four-cable crane, max 20.2 N", "acroboter_4cable", 20.2, 5.0, "tensions 19.98..20.30 N unbounded"),
)


def limited_spec_text(text: str, upper: float, lower: float | None = None) -> str:
    """A spec's TOML with every winch actuator's limits set to [lower, upper] (lower: the spec's, else 0)."""
    blocks = re.split(r"(?=^\[\[actuators\]\])", text, flags=re.M)
    out = []
    for block in blocks:
        if block.startswith("[[actuators]]") and re.search(r'^kind\s*=\s*"winch_tension"', block, flags=re.M):
            found = re.search(r"^limits\s*=\s*\[\s*([^,\]]+),", block, flags=re.M)
            low = lower if lower is not None else (float(found.group(1)) if found else 0.0)
            block = re.sub(r"^limits\s*=.*\n", "", block, flags=re.M)
            block = re.sub(r'^(cable\s*=\s*"[^"]*".*\n)', rf"\1limits = [{low!r}, {upper!r}]\n", block,
                           count=1, flags=re.M)
        out.append(block)
    return "".join(out)


@dataclass
class Measures:
    scenario: str
    method: str
    strategy: str
    max_position_error_mm: float
    rms_position_error_mm: float
    max_yaw_error_deg: float
    max_tilt_deg: float
    time_on_limits_s: float
    limit_episodes: int
    last_on_limit_s: float | None
    recovery_s: float | None
    worst_beyond_limits: float
    finite: bool
    diverged_at: float | None
    wall_s: float

    def row(self) -> dict:
        return asdict(self)


def measure(result, lower: np.ndarray, upper: np.ndarray, scenario: str, strategy: str, wall: float) -> Measures:
    """The figures of one run (module docstring) from its Result."""
    t = result.time
    err = result.position_error_mm
    yaw = result.yaw_error_deg
    on = (result.run.limit_state != 0).any(axis=1)
    period = result.run.control_period
    held = on[:-1] if on.size > 1 else on
    starts = np.count_nonzero(on[1:] & ~on[:-1]) + (1 if on.size and on[0] else 0)
    last = float(t[np.flatnonzero(on)[-1]]) if on.any() else None
    recovery = None
    if last is not None:
        after = t > last
        bad = np.flatnonzero(after & (err >= RECOVERED_MM))
        if not after.any():
            recovery = None
        elif bad.size == 0:
            recovery = float(t[np.flatnonzero(after)[0]] - last)
        elif bad[-1] + 1 < t.size:
            recovery = float(t[bad[-1] + 1] - last)
    u = result.u
    beyond = float(np.maximum(np.maximum(u - upper, lower - u), 0.0).max()) if u.size else 0.0
    return Measures(
        scenario=scenario, method=result.method, strategy=strategy,
        max_position_error_mm=float(err.max()), rms_position_error_mm=float(np.sqrt(np.mean(err**2))),
        max_yaw_error_deg=float(np.abs(yaw).max()) if yaw is not None else 0.0,
        max_tilt_deg=float(result.tilt_deg.max()),
        time_on_limits_s=float(np.count_nonzero(held) * period), limit_episodes=int(starts),
        last_on_limit_s=last, recovery_s=recovery, worst_beyond_limits=beyond,
        finite=bool(np.isfinite(u).all() and np.isfinite(result.q).all()),
        diverged_at=result.diverged_at, wall_s=wall,
    )


def run_scenario(scenario: Scenario, methods=("mlm", "penalty", "iterative-3"), strategies=STRATEGIES,
                 folder=None, duration: float | None = None) -> tuple[list[Measures], dict]:
    """Every method under every strategy on one scenario: (measures, {(method, strategy): Result})."""
    from pathlib import Path
    from tempfile import TemporaryDirectory

    from ..api.crane import Crane
    from ..model.locations import example_spec

    text = limited_spec_text(example_spec(scenario.spec).read_text(), scenario.upper, scenario.lower)
    with TemporaryDirectory() as tmp:
        path = Path(folder or tmp) / f"{scenario.spec}_limited.toml"
        path.write_text(text)
        crane = Crane.from_toml(path)
    lower, upper, _ = crane.spec.input_limits()
    measures, results = [], {}
    for method in methods:
        for strategy in strategies:
            start = time.perf_counter()
            result = crane.simulate(method, duration=duration, saturation=strategy, warm_up=0)
            wall = time.perf_counter() - start
            results[(method, strategy)] = result
            measures.append(measure(result, lower, upper, scenario.name, strategy, wall))
    return measures, results

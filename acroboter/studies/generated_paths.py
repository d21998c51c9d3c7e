"""Paths nobody planned: short waypoint paths drawn at random on the default and the four-cable crane, each with
winch limits drawn where its statics leave 5-20 % of the span, planned with `plan --tolerance` and flown by every
method with the limits applied (docs/planning.md, "Generated paths"; `make plan-fuzz`).

A path: 2 or 3 straight edges from the crane's start, each 5-20 cm long in a random direction (its vertical part
scaled by VERTICAL_SHARE: a crane's paths are mostly horizontal, as the paper's), the whole path turning the unit
by 0 or up to ±45° of yaw. Its limits: every winch's lower limit LOWER_N, its upper one set so that the largest
winch tension that holds the load at rest anywhere on the path (acroboter.planning.checks.static_needs) leaves a
drawn fraction of the span, `static_room`, below it. The plan's margin (MARGIN) takes part of that room, the motion
the rest.

What each path must give (`verdict`, the issue's acceptance):

- planned: the tolerance met by every method at every clock phase (acroboter.planning.tolerance);
- no instant on a limit in any flight (the certificate's `saturated_s` 0 for every method);
- no planned input beyond the limits less the margin at any instant, on the planner's 1 ms grid;
- faster than the best uniform slowdown of the time-optimal timing whose flights meet the same tolerance.

A path is drawn from a seed (`drawn_path(RandomDraw(seed), spec)`: the same path on every machine) or by hypothesis
in the tests (tests/test_generated_paths.py draws through the same function, so a failing path shrinks).
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ..model.crane_generator import Draw
from ..model.spec_edits import with_path, with_winch_limits

SPECS = ("acroboter", "acroboter_4cable")
EDGES = (2, 3)
EDGE_LENGTH_M = (0.05, 0.20)
VERTICAL_SHARE = 0.4  # a random direction's vertical component, scaled by this before it is normalised
YAW_DEG = 45.0  # ± the whole path's yaw turn, when it turns (half of the paths)
STATIC_ROOM = (0.05, 0.20)  # of the winch span: what the statics leave below the upper limit
LOWER_N = 5.0
MARGIN = 0.02
TOLERANCE_M = 1e-4
INTERVALS = 12
METHODS = ("mlm", "penalty", "iterative-3")


@dataclass(frozen=True)
class DrawnPath:
    """A path's waypoints (m, relative to the start), its yaw turn (°) and the room its statics leave (fraction of
    the winch span below the upper limit), on a shipped spec."""

    spec: str
    waypoints: tuple[tuple[float, float, float], ...]
    yaw_deg: float
    static_room: float

    @property
    def edges(self) -> int:
        return len(self.waypoints) - 1

    def spec_text(self) -> str:
        """The shipped spec's TOML with this path's waypoints and yaw (its limits as shipped)."""
        from ..process.locations import example_spec

        return with_path(example_spec(self.spec).read_text(), self.waypoints, self.yaw_deg)


def drawn_path(draw: Draw, spec: str) -> DrawnPath:
    """A path on `spec` (see the module), its numbers from `draw` (acroboter.model.crane_generator.RandomDraw, or
    hypothesis)."""
    point = np.zeros(3)
    points = [(0.0, 0.0, 0.0)]
    for _ in range(draw.integer(*EDGES)):
        # a direction from the angles (uniform on the sphere), its vertical part scaled down
        azimuth = draw.uniform(0.0, 2.0 * math.pi)
        rise = draw.uniform(-1.0, 1.0)
        flat = math.sqrt(1.0 - rise * rise)
        direction = np.array([flat * math.cos(azimuth), flat * math.sin(azimuth), VERTICAL_SHARE * rise])
        if np.linalg.norm(direction) < 1e-3:  # straight up or down, scaled to nothing: go up
            direction = np.array([0.0, 0.0, 1.0])
        point = point + draw.uniform(*EDGE_LENGTH_M) * direction / np.linalg.norm(direction)
        points.append(tuple(float(c) for c in point))
    turns = draw.integer(0, 1)
    yaw = draw.uniform(-YAW_DEG, YAW_DEG) if turns else 0.0
    return DrawnPath(spec, tuple(points), float(yaw), float(draw.uniform(*STATIC_ROOM)))


def crane_of(text: str, file: Path):
    """The Crane of a spec's TOML text, written to `file` first (the spec's file, kept beside the results)."""
    from ..api.crane import Crane

    file.parent.mkdir(parents=True, exist_ok=True)
    file.write_text(text)
    return Crane.from_toml(file)


def winch_limits(path: DrawnPath, folder: Path) -> tuple[float, float, float, float]:
    """(lower, upper, least, largest): the winch limits that leave `static_room` of the span above the largest
    static need along the path, and the least and largest winch tension at rest along it (N)."""
    from ..planning.checks import static_needs
    from ..planning.geometry import PathGeometry

    crane = crane_of(path.spec_text(), folder / "shipped_limits.toml")
    model = crane.model.data()
    winches = [i for i, actuator in enumerate(crane.spec.actuators) if actuator.kind == "winch_tension"]
    _, _, needs = static_needs(model, PathGeometry(crane.desired()))
    least, largest = float(needs[:, winches].min()), float(needs[:, winches].max())
    room = path.static_room
    upper = (largest - room * LOWER_N) / (1.0 - room)
    return LOWER_N, float(upper), least, largest


@dataclass
class PathResult:
    """One path's plan and flights: the figures `verdict` judges and the report lists."""

    name: str
    spec: str
    edges: int
    waypoints: list
    yaw_deg: float
    static_room: float
    winch_limits: list[float]
    static_tensions: list[float]  # least, largest winch tension at rest along the path (N)
    status: str  # the plan's: planned, or why not
    planned_s: float | None = None
    time_optimal_s: float | None = None
    time_optimal_flown_mm: float | None = None
    uniform_s: float | None = None  # the best uniform slowdown of the time-optimal timing meeting the tolerance
    flown_mm: float | None = None  # the worst flight, every method and clock phase
    flights: dict = field(default_factory=dict)  # method -> its certificate figures (error, saturated_s, ...)
    margin_achieved: float | None = None  # of the span, planned inputs on the 1 ms grid
    rounds: int = 0
    plan_s: float = 0.0
    failures: list[str] = field(default_factory=list)

    def row(self) -> dict:
        return asdict(self)


def run_path(path: DrawnPath, name: str, folder: Path, tolerance: float = TOLERANCE_M, margin: float = MARGIN,
             intervals: int = INTERVALS, methods=METHODS) -> PathResult:
    """Plan `path` to the tolerance with its drawn limits and judge it (`verdict`); its spec (`spec.toml`) and
    planned trajectory (`plan.csv`, also when it fails) in `folder`."""
    from ..planning.ideal_motion import PlanningError
    from ..planning.planner import PlanFailure

    lower, upper, least, largest = winch_limits(path, folder)
    text = with_winch_limits(path.spec_text(), upper, lower)
    result = PathResult(name, path.spec, path.edges, [list(p) for p in path.waypoints], path.yaw_deg,
                        path.static_room, [lower, upper], [least, largest], "not planned")
    crane = crane_of(text, folder / "spec.toml")
    started = time.perf_counter()
    try:
        plan = crane.plan(margin=margin, intervals=intervals, tolerance=tolerance, certify=list(methods))
    except PlanFailure as err:  # written and judged all the same: its figures say what failed
        plan = err.plan
    except PlanningError as err:
        result.status = f"no plan: {err}"
        result.plan_s = time.perf_counter() - started
        result.failures = verdict(result, margin, tolerance)
        return result
    result.plan_s = time.perf_counter() - started
    summary = plan.summary()
    record = summary.get("tolerance") or {}
    result.status = summary["status"]
    result.planned_s = float(plan.duration)
    result.time_optimal_s = record.get("time_optimal_duration_s")
    result.time_optimal_flown_mm = record.get("time_optimal_flown_mm")
    result.uniform_s = record.get("uniform_slowdown_duration_s")
    result.flown_mm = record.get("flown_mm")
    result.rounds = len(record.get("rounds", []))
    result.flights = (summary.get("certificate") or {}).get("flights", {})
    result.margin_achieved = summary.get("margin_achieved")
    plan.to_csv(folder / "plan.csv")
    result.failures = verdict(result, margin, tolerance, plan.failures)
    return result


def verdict(result: PathResult, margin: float, tolerance: float, plan_failures=()) -> list[str]:
    """What the path fails of the acceptance (empty: it passes): see the module."""
    out = list(plan_failures)
    if result.planned_s is None:
        return [result.status, *out]
    if result.flown_mm is None or not result.flown_mm <= 1e3 * tolerance:
        out.append(f"flown at {result.flown_mm} mm, beyond the tolerance {1e3 * tolerance:g} mm")
    held = {m: f.get("saturated_s", 0.0) for m, f in result.flights.items() if f.get("saturated_s", 0.0) > 0}
    if held:
        out.append("on a limit: " + ", ".join(f"{m} {s:.3g} s" for m, s in held.items()))
    if result.margin_achieved is None or result.margin_achieved < margin * (1.0 - 1e-6):
        out.append(f"a planned input within {result.margin_achieved} of the span of its limit, less than the "
                   f"margin {margin:g} (1 ms grid)")
    if result.uniform_s is not None and not result.planned_s < result.uniform_s:
        out.append(f"not faster than the uniform slowdown meeting the tolerance ({result.planned_s:.4g} s against "
                   f"{result.uniform_s:.4g} s)")
    return list(dict.fromkeys(out))  # the plan's failures and the checks' may say the same thing

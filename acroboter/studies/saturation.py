"""Saturation strategies side by side (docs/saturation.md): the bounded least squares ("qp") against saturation as
underactuation, on cranes whose winch limits sit just below what their path needs, and on a path planned under
the limits (acroboter.planning) and then flown faster than the plan.

A scenario is a shipped spec with its winches' limits changed (the TOML text, so that the library is the
shipped one: limits are read at run time), optionally with other waypoints. Its path is the spec's own timing,
or (`speedup`) the fastest timing `Crane.plan` finds under the limits less PLAN_MARGIN, compressed in time by
`speedup` (acroboter.control.path.sped_up; 1: the plan itself) and followed by SETTLE_S at rest. Each run is
measured from its records alone:

- position error (max, rms, mm; the max also up to the path's end), yaw error (max, deg), tilt (max, deg);
- time on limits: the control periods with any input held at a limit (limit_state ≠ 0), s; the number of
  episodes (a run of such periods), a chatter count, and how many start up to the path's end;
- recovery per episode: from the last period of an episode on a limit, the time until the position error is
  below RECOVERED_MM and stays there until the next episode starts (or the run ends); None: it is not (the
  error is still at or above it when the next episode starts or the run ends). Reported as their median (an
  episode not recovered counts as longer than any), the longest recovered one, and how many did not recover;
  `recovery_s` is the last episode's (the recovery "after the last episode" of the first study);
- the worst excursion of any input beyond its limits (must be 0: never a silent clip, never beyond), whether
  every input and state stayed finite, and where the run diverged (the plant's checks), if it did.
"""

from __future__ import annotations

import hashlib
import json
import re
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ..model.spec_edits import with_path, with_winch_limits

RECOVERED_MM = 1.0  # position error below which a run has recovered (the unsaturated runs track to 0.06 mm)
STRATEGIES = ("qp", "underactuation")
# The planned scenarios: the plan keeps every input within its limits less this fraction of the span
# (docs/planning.md), on this many optimiser intervals (at least 6 per edge), and each run rests this long after
# the trajectory's end, so that an episode near the end has time to recover.
PLAN_MARGIN = 0.05
PLAN_INTERVALS = 12
SETTLE_S = 2.0
# The paper path's first two edges (+x, then +y, 0.25 m each; the spec's yaw turn, 90° over the two). The whole
# lower square (four edges) was asked for, but its plan had not converged after 5 min (IPOPT wandering in its
# restoration phase with 24 and with 40 intervals, 2026-12-03); two edges plan in about 25 s. With 24 intervals
# the two-edge plan is more nearly bang-bang and MLM's flight of it leaves the 5 % margin (certificate failed).
TWO_EDGES = ((0.0, 0.0, 0.0), (0.25, 0.0, 0.0), (0.25, 0.25, 0.0))


@dataclass(frozen=True)
class Scenario:
    name: str  # a label for the tables
    spec: str  # a shipped spec's name (acroboter.example_spec)
    upper: float  # N, every winch's upper limit
    lower: float | None = None  # N, every winch's lower limit (None: the spec's)
    note: str = ""
    waypoints: tuple | None = None  # the path's waypoints instead of the spec's
    speedup: float | None = None  # None: the spec's own timing; f: the planned timing flown f times faster


# The scenarios nobody tuned for: the default crane just below its peak need (26.91 N at t = 25.14 s;
# static 26.75 N), the four-cable crane with a tight upper limit (its tensions span 19.98..20.30 N on the path,
# the static share 20.07 N), and two edges of the lower square planned under [5, 30] N with a 5 % margin (bounds
# [6.25, 28.75] N), flown as planned (the control case) and 1.15 and 1.3 times faster (accelerations x1.32, x1.69).
SCENARIOS = (
    Scenario("default crane, max 26.9 N", "acroboter", 26.9, 0.0, "peak need 26.91 N"),
    Scenario("default crane, max 27.0 N", "acroboter", 27.0, 0.0, "peak need 27.06 N at the column's turn"),
    Scenario("four-cable crane, max 20.2 N", "acroboter_4cable", 20.2, 5.0, "tensions 19.98..20.30 N unbounded"),
    Scenario("two edges, planned", "acroboter", 30.0, 5.0, "the plan itself", TWO_EDGES, 1.0),
    Scenario("two edges, planned x1.15", "acroboter", 30.0, 5.0, "1.15 times faster", TWO_EDGES, 1.15),
    Scenario("two edges, planned x1.3", "acroboter", 30.0, 5.0, "1.3 times faster", TWO_EDGES, 1.3),
)


def scenario_spec_text(scenario: Scenario) -> str:
    """The scenario's spec as TOML: the shipped one with its winches' limits and, if given, its waypoints."""
    from ..process.locations import example_spec

    text = with_winch_limits(example_spec(scenario.spec).read_text(), scenario.upper, scenario.lower)
    if scenario.waypoints is not None:
        text = with_path(text, scenario.waypoints)
    return text


def plan_key(text: str, margin: float = PLAN_MARGIN, intervals: int = PLAN_INTERVALS) -> str:
    """What a plan is computed from (the spec's text, the margin, the intervals), hashed: the cache's key."""
    return hashlib.sha256(f"{text}\nmargin = {margin!r}\nintervals = {intervals!r}\n".encode()).hexdigest()[:16]


_PLANS: dict = {}  # key -> (trajectory, summary): one plan per process for the scenarios that share it


def planned_trajectory(crane, text: str, cache: Path | None = None):
    """(trajectory, summary) of `crane.plan(margin=PLAN_MARGIN, intervals=PLAN_INTERVALS, corners="swing",
    certify=False)` (as measured: the swing carried over its one corner) for the crane built from `text`: computed
    here, or read back from `cache`/plan-<key>.csv and .json (written when computed)."""
    from ..control.trajectory_file import read_trajectory_csv, write_trajectory_csv

    key = plan_key(text)
    if key in _PLANS:
        return _PLANS[key]
    files = (Path(cache) / f"plan-{key}.csv", Path(cache) / f"plan-{key}.json") if cache is not None else None
    if files is not None and all(f.is_file() for f in files):
        found = read_trajectory_csv(files[0]), json.loads(files[1].read_text())
    else:
        start = time.perf_counter()
        # not certified: the study flies the plan itself, and on past its end, where holding the connector's
        # swing asks more than the limits (what it studies; the certificate, which flies 1 s past the end, refuses it)
        plan = crane.plan(margin=PLAN_MARGIN, intervals=PLAN_INTERVALS, corners="swing", certify=False)
        summary = {"key": key, "wall_s": time.perf_counter() - start, **plan.summary()}
        found = plan.trajectory, summary
        if files is not None:
            files[0].parent.mkdir(parents=True, exist_ok=True)
            write_trajectory_csv(files[0], plan.trajectory)
            files[1].write_text(json.dumps(summary, indent=1) + "\n")
    _PLANS[key] = found
    return found


@dataclass
class Measures:
    scenario: str
    method: str
    strategy: str
    duration_s: float
    path_end_s: float  # where the path ends (a planned one: then SETTLE_S at rest)
    max_position_error_mm: float
    max_position_error_on_path_mm: float  # up to path_end_s
    rms_position_error_mm: float
    max_yaw_error_deg: float
    max_tilt_deg: float
    time_on_limits_s: float
    limit_episodes: int
    episodes_on_path: int  # of them, those that start up to path_end_s
    last_on_limit_s: float | None
    recovery_s: float | None  # after the last episode (None: not recovered)
    recovery_median_s: float | None  # per episode, an episode not recovered counting as longer than any
    recovery_worst_s: float | None  # the longest of the episodes that recovered (None: none did)
    episodes_not_recovered: int
    episode_recoveries_s: list
    worst_beyond_limits: float
    max_unbounded_input: float  # the largest |u| of an input without limits (N or N·m)
    max_unbounded_input_name: str | None
    finite: bool
    diverged_at: float | None
    divergence: str | None  # why the run was stopped, if it was
    wall_s: float

    def row(self) -> dict:
        return asdict(self)


def limit_episodes(on: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) index of each run of consecutive True in `on`."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], np.asarray(on, dtype=np.int8), [0]])))
    return [(int(a), int(b) - 1) for a, b in zip(edges[0::2], edges[1::2], strict=True)]


def episode_recoveries(t: np.ndarray, on: np.ndarray, err: np.ndarray, below: float = RECOVERED_MM
                       ) -> list[float | None]:
    """For each episode on a limit (a run of `on`), the time from its last instant until `err` is below `below`
    and stays there up to the next episode's first instant (or the end): t[k] − t[last] for the first such k
    after it; None when `err` is not below at the instant before the next episode (or at the end), or no
    instant is left before them."""
    episodes = limit_episodes(on)
    out = []
    for i, (_, last) in enumerate(episodes):
        stop = episodes[i + 1][0] if i + 1 < len(episodes) else t.size
        window = err[last + 1 : stop]
        if window.size == 0 or window[-1] >= below:
            out.append(None)
            continue
        bad = np.flatnonzero(window >= below)
        k = last + 1 + (int(bad[-1]) + 1 if bad.size else 0)
        out.append(float(t[k] - t[last]))
    return out


def recovery_figures(recoveries: list[float | None]) -> tuple[float | None, float | None, int]:
    """(median, longest recovered, how many not recovered) of per-episode recoveries; in the median an episode
    not recovered counts as longer than any (None when the median falls on one)."""
    if not recoveries:
        return None, None, 0
    times = np.array([np.inf if r is None else r for r in recoveries])
    median = float(np.median(times))
    done = times[np.isfinite(times)]
    return (median if np.isfinite(median) else None, float(done.max()) if done.size else None,
            int(np.count_nonzero(~np.isfinite(times))))


def measure(result, lower: np.ndarray, upper: np.ndarray, scenario: str, strategy: str, wall: float,
            path_end: float | None = None) -> Measures:
    """The figures of one run (module docstring) from its Result; `path_end`: where its path ends (None: with
    the run)."""
    t = result.time
    path_end = float(t[-1]) if path_end is None else float(path_end)
    err = result.position_error_mm
    yaw = result.yaw_error_deg
    on = (result.run.limit_state != 0).any(axis=1)
    period = result.run.control_period
    held = on[:-1] if on.size > 1 else on
    last = float(t[np.flatnonzero(on)[-1]]) if on.any() else None
    recoveries = episode_recoveries(t, on, err)
    median, worst, not_recovered = recovery_figures(recoveries)
    u = result.u
    beyond = float(np.maximum(np.maximum(u - upper, lower - u), 0.0).max()) if u.size else 0.0
    free = np.flatnonzero(~np.isfinite(lower) & ~np.isfinite(upper))
    size = np.abs(u[:, free]).max(axis=0) if free.size and u.size else np.zeros(0)
    names = getattr(getattr(result, "layout", None), "inputs", None)
    return Measures(
        scenario=scenario, method=result.method, strategy=strategy, duration_s=float(t[-1]), path_end_s=path_end,
        max_position_error_mm=float(err.max()), max_position_error_on_path_mm=float(err[t <= path_end].max()),
        rms_position_error_mm=float(np.sqrt(np.mean(err**2))),
        max_yaw_error_deg=float(np.abs(yaw).max()) if yaw is not None else 0.0,
        max_tilt_deg=float(result.tilt_deg.max()),
        time_on_limits_s=float(np.count_nonzero(held) * period), limit_episodes=len(recoveries),
        episodes_on_path=sum(1 for first, _ in limit_episodes(on) if t[first] <= path_end),
        last_on_limit_s=last, recovery_s=recoveries[-1] if recoveries else None, recovery_median_s=median,
        recovery_worst_s=worst, episodes_not_recovered=not_recovered, episode_recoveries_s=recoveries,
        worst_beyond_limits=beyond, max_unbounded_input=float(size.max()) if size.size else 0.0,
        max_unbounded_input_name=(names[free[size.argmax()]] if names is not None and size.size else None),
        finite=bool(np.isfinite(u).all() and np.isfinite(result.q).all()),
        diverged_at=result.diverged_at, divergence=getattr(result.run, "divergence", None), wall_s=wall,
    )


def run_scenario(scenario: Scenario, methods=("mlm", "penalty", "iterative-3"), strategies=STRATEGIES,
                 folder=None, duration: float | None = None, plans: Path | None = None
                 ) -> tuple[list[Measures], dict, dict | None]:
    """Every method under every strategy on one scenario: (measures, {(method, strategy): Result}, for a planned
    scenario {"plan": the plan's summary, "unlimited": unlimited_reference(...)}, else None). `plans`: where planned
    trajectories are cached (planned_trajectory)."""
    from ..control.path import sped_up

    text = scenario_spec_text(scenario)
    crane = _crane(text, scenario.spec, folder)
    lower, upper, _ = crane.spec.input_limits()
    trajectory, extra, path_end = None, None, None
    if scenario.speedup is not None:
        planned, summary = planned_trajectory(crane, text, plans)
        trajectory = sped_up(planned, scenario.speedup)
        duration = trajectory.duration + SETTLE_S if duration is None else duration
        path_end = trajectory.duration
        reference = unlimited_reference(text, scenario, trajectory, duration, path_end, methods, folder)
        extra = {"plan": summary, "unlimited": reference}
    measures, results = [], {}
    for method in methods:
        for strategy in strategies:
            start = time.perf_counter()
            result = crane.simulate(method, duration=duration, trajectory=trajectory, saturation=strategy, warm_up=0)
            wall = time.perf_counter() - start
            results[(method, strategy)] = result
            measures.append(measure(result, lower, upper, scenario.name, strategy, wall, path_end))
    return measures, results, extra


def _crane(text: str, name: str, folder=None):
    from tempfile import TemporaryDirectory

    from ..api.crane import Crane

    with TemporaryDirectory() as tmp:
        path = Path(folder or tmp) / f"{name}_limited.toml"
        path.write_text(text)
        return Crane.from_toml(path)


def unlimited_reference(text: str, scenario: Scenario, trajectory, duration: float, path_end: float, methods,
                        folder=None) -> list[dict]:
    """The same flights with every input limit removed from the spec: what they ask of the winches on the path
    (t ≤ path_end) and after it, the first instant a winch would go beyond the scenario's upper limit, and the
    position error, on the path, after it and at the end."""
    crane = _crane(re.sub(r"^limits\s*=.*\n", "", text, flags=re.M), scenario.spec, folder)
    winches = [k for k, name in enumerate(crane.layout.inputs) if name.startswith("tension")]
    rows = []
    for method in methods:
        r = crane.simulate(method, duration=duration, trajectory=trajectory, warm_up=0)
        t, u, err = r.time, r.u[:, winches], r.position_error_mm
        on, after = t <= path_end, t > path_end
        beyond = np.flatnonzero((u > scenario.upper).any(axis=1))
        rows.append({"scenario": scenario.name, "method": method, "diverged_at": r.diverged_at,
                     "max_winch_on_path_n": float(u[on].max()), "min_winch_on_path_n": float(u[on].min()),
                     "max_winch_after_n": float(u[after].max()) if after.any() else None,
                     "first_beyond_upper_s": float(t[beyond[0]]) if beyond.size else None,
                     "max_position_error_on_path_mm": float(err[on].max()),
                     "max_position_error_after_mm": float(err[after].max()) if after.any() else None,
                     "end_position_error_mm": float(err[-1])})
    return rows

"""The toolchain and both plants on cranes nobody drew (`acroboter plant-fuzz --cranes N`, `make plant-fuzz-cranes`).

Each crane comes from acroboter.model.crane_generator (crane `seed`: the same crane on every machine). One task
per crane (`run_crane`, a Dask task: module level, so that it pickles):

1. **Its equilibrium** (`check_crane`): the static equilibrium at the path's start with every winch pulling, at
   least REJECT_SHARE of its static share (the unit's weight over the winches) and within its limits; a crane
   without one is *rejected*, the reason given, and is no failure: the generator draws geometries some of which
   cannot hang (an anchor layout that leaves the unit's centre outside the cables' reach).
2. **Its code**: generated and compiled (cached), then generated again into a temporary folder and compared byte
   for byte with the first (what `make check-generated` checks of the shipped specs): deterministic code.
3. **Open loop** (`cases` experiments, acroboter.studies.plant_differential: the same experiments and the same
   rules as the fuzz of the shipped specs), the own plant against MuJoCo.
4. **Closed loop**, every method (MLM, penalty, iterative with each of the spec's counts):
   - the whole path (the paper's, scaled to the crane's connector) on the own plant, its tracking error within
     TRACKING_BOUND_M, no input on a limit, never diverged (a diverged run says why; the loop's stability at the
     start, acroboter.sim.loop_stability, is in every row: a cause where it is unstable);
   - the first CLOSED_LOOP_MUJOCO_S of it on the MuJoCo plant at its default step (the crane's own,
     acroboter.sim.mujoco_step): the bodies' centres within CLOSED_LOOP_BOUND_M of the own plant's (the same
     controller closes the loop around each).

A crane's rows: one in cranes.csv (what was drawn, the checks, the times), one per experiment in plant_fuzz.csv, one
per method in closed_loop.csv.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from ..model.crane_generator import SHARE_LIMITS, crane_name, crane_spec

# Every winch pulls at least this fraction of its static share at the start (a cable near slack at rest is a crane
# that cannot hang, not a test of the plants).
REJECT_SHARE = SHARE_LIMITS[0]
TRACKING_BOUND_M = 1e-3  # the issue's: every method tracks the scaled paper path within 1 mm
CLOSED_LOOP_MUJOCO_S = 10.0  # s of the path flown on MuJoCo too (its step costs ~0.4 s of CPU per simulated s)
CLOSED_LOOP_BOUND_M = 20e-6  # the plants' tracked points, each in its own closed loop, as the open loop's bound

CRANE_COLUMNS = ["crane", "seed", "status", "winches", "cc_mass_kg", "su_mass_kg", "min_drum_kg", "max_drum_kg",
                 "main_cable_m", "cc_radius_m", "su_radius_m", "drop_m", "min_start_share", "max_start_share",
                 "deterministic_code", "build_s", "open_loop_failed", "closed_loop_failed", "wall_s"]
CLOSED_COLUMNS = ["crane", "method", "passed", "status", "max_error_mm", "saturated_steps", "diverged_at",
                  "loop_cause", "zero_dynamics_growth_per_s", "sampled_growth_per_s",
                  "mujoco_s", "mujoco_max_error_mm", "plants_max_diff_m", "mujoco_timestep", "replay"]


class CraneRejected(Exception):
    """A generated crane without a static equilibrium in which every winch pulls: the reason."""


def describe(spec) -> dict:
    """What was drawn, for the report: a crane's row before its checks."""
    winches = [c for c in spec.cables if c.winch is not None]
    cc, su = spec.body("CC"), spec.body("SU")
    cc_point, su_point = cc.point("a1"), su.point("b1")
    return {"crane": spec.name, "winches": len(winches), "cc_mass_kg": cc.mass, "su_mass_kg": su.mass,
            "min_drum_kg": min(c.winch.reflected_inertia for c in winches),
            "max_drum_kg": max(c.winch.reflected_inertia for c in winches),
            "main_cable_m": next(c.length for c in spec.cables if c.name == "main"),
            "cc_radius_m": float(np.hypot(*cc_point[:2])), "su_radius_m": float(np.hypot(*su_point[:2])),
            "drop_m": cc.initial_position[2] - su.initial_position[2]}


def check_crane(crane) -> tuple[float, float]:
    """The least and largest winch tension at the start, in static shares; CraneRejected when there is no
    equilibrium or a winch pulls less than REJECT_SHARE of its share or is beyond its limits."""
    from ..sim.statics import EquilibriumError

    try:
        start = crane.equilibrium()
    except EquilibriumError as err:
        raise CraneRejected(str(err)) from None
    return start_shares(crane.spec, crane.inputs, start.inputs)


def start_shares(spec, names: list[str], inputs: np.ndarray) -> tuple[float, float]:
    """The least and largest winch tension of `inputs` (the start's), in static shares (the unit's weight over the
    winches); CraneRejected when one pulls less than REJECT_SHARE of it or is beyond its limits."""
    winch = [i for i, a in enumerate(spec.actuators) if a.kind == "winch_tension"]
    share = spec.body("SU").mass * abs(spec.gravity[2]) / len(winch)
    tensions = np.asarray(inputs)[winch] / share
    lower, upper, _ = spec.input_limits()
    if tensions.min() < REJECT_SHARE:
        weakest = winch[int(np.argmin(tensions))]
        raise CraneRejected(f"at rest {names[weakest]} pulls {inputs[weakest]:.3g} N, "
                            f"{tensions.min():.3g} of its static share (at least {REJECT_SHARE:g})")
    beyond = [names[i] for i in winch if not lower[i] <= inputs[i] <= upper[i]]
    if beyond:
        raise CraneRejected(f"at rest {', '.join(beyond)} would be beyond the spec's limits")
    return float(tensions.min()), float(tensions.max())


def deterministic_code(spec, source: Path) -> bool:
    """The spec generated again, into a temporary folder, is byte for byte the code it was built from."""
    from ..codegen.emit_c import generate
    from ..runtime.integrity import compare_trees

    with tempfile.TemporaryDirectory(prefix="acroboter-crane-check-") as tmp:
        fresh = generate(spec, Path(tmp))
        return not compare_trees(fresh, source)


def run_crane(seed: int, cases: int, case_seed: int, closed_loop: bool = True,
              mujoco_timestep: float | None = None) -> dict:
    """Crane `seed` through every check of the module docstring: {"crane": row, "open": rows, "closed": rows}."""
    from ..api.crane import Crane
    from .plant_differential import MUJOCO_TIMESTEP, experiment_of, outcome_row, remember_crane, run_experiment

    t0 = time.perf_counter()
    spec = crane_spec(seed)
    row = describe(spec) | {"seed": seed, "status": "agrees", "open_loop_failed": 0, "closed_loop_failed": 0}
    crane = Crane.from_spec(spec)
    row["build_s"] = round(time.perf_counter() - t0, 2)
    remember_crane(crane)
    out: dict = {"crane": row, "open": [], "closed": []}
    try:
        row["min_start_share"], row["max_start_share"] = check_crane(crane)
    except CraneRejected as err:
        row["status"] = f"rejected: {err}"
        row["wall_s"] = round(time.perf_counter() - t0, 2)
        return out
    row["deterministic_code"] = deterministic_code(spec, crane.model.source_dir)
    step = mujoco_timestep or MUJOCO_TIMESTEP
    for i in range(cases):
        outcome = run_experiment(experiment_of(spec.name, case_seed + i), crane, step)
        out["open"].append(outcome_row(outcome, case_seed + i))
    if closed_loop:
        out["closed"] = closed_loop_rows(crane, mujoco_timestep)
    row["open_loop_failed"] = sum(not r["passed"] for r in out["open"])
    row["closed_loop_failed"] = sum(not r["passed"] for r in out["closed"])
    problems = [f"{row['open_loop_failed']} open-loop case(s) disagree"] if row["open_loop_failed"] else []
    problems += [f"{r['method']}: {r['status']}" for r in out["closed"] if not r["passed"]]
    if not row["deterministic_code"]:
        problems.insert(0, "its code generated twice differs")
    if problems:
        row["status"] = "fails: " + "; ".join(problems)
    row["wall_s"] = round(time.perf_counter() - t0, 2)
    return out


def closed_loop_rows(crane, mujoco_timestep: float | None) -> list[dict]:
    """Every method on the whole path (own plant), and on its first CLOSED_LOOP_MUJOCO_S on both plants."""
    from ..sim.loop_stability import loop_stability
    from ..sim.mujoco_step import crane_step
    from .plant_differential import generated_seed

    spec = crane.spec
    methods = ["mlm", "penalty"] + [f"iterative-{n}" for n in spec.controller.penalty.iterations]
    rows = []
    for method in methods:
        name, _, count = method.partition("-")
        kwargs = {"iterations": int(count)} if count else {}
        row = {"crane": spec.name, "method": method, "replay": replay_command(generated_seed(spec.name))}
        whole = crane.simulate(name, **kwargs)
        row["max_error_mm"] = float(np.max(whole.position_error_mm))
        saturated = np.asarray(whole.saturated)  # per instant (a row per instant and input, where it is 2-D)
        row["saturated_steps"] = int(np.count_nonzero(saturated.any(axis=-1) if saturated.ndim > 1 else saturated))
        row["diverged_at"] = whole.diverged_at
        stability = loop_stability(crane.model, crane.path, crane.gains(), method, crane.equilibrium().q,
                                   np.zeros(crane.layout.n), 0.0)
        row["loop_cause"] = stability.cause or ""
        row["zero_dynamics_growth_per_s"] = stability.zero_dynamics_growth
        row["sampled_growth_per_s"] = stability.sampled_growth
        span = min(CLOSED_LOOP_MUJOCO_S, float(whole.time[-1]))
        own = crane.simulate(name, duration=span, **kwargs)
        engine = crane.simulate(name, duration=span, plant="mujoco", mujoco_timestep=mujoco_timestep, **kwargs)
        row["mujoco_s"] = span
        row["mujoco_timestep"] = mujoco_timestep or crane_step(crane.model, crane.equilibrium())[0]
        row["mujoco_max_error_mm"] = float(np.max(engine.position_error_mm))
        steps = min(len(own.time), len(engine.time))
        row["plants_max_diff_m"] = max(
            float(np.linalg.norm(own.q[:steps, b : b + 3] - engine.q[:steps, b : b + 3], axis=1).max())
            for b in crane.layout.body_offset.values())
        problems = []
        if whole.diverged_at is not None or engine.diverged_at is not None:
            run = whole if whole.diverged_at is not None else engine
            problems.append(f"diverged at t = {run.diverged_at:.3f} s ({run.run.divergence})")
        if row["max_error_mm"] > TRACKING_BOUND_M * 1e3:
            problems.append(f"tracks the path at {row['max_error_mm']:.3g} mm (bound {TRACKING_BOUND_M * 1e3:g})")
        if row["saturated_steps"]:
            problems.append(f"an input on a limit in {row['saturated_steps']} control steps")
        if row["plants_max_diff_m"] > CLOSED_LOOP_BOUND_M:
            problems.append(f"the plants' bodies' centres differ by {row['plants_max_diff_m'] * 1e6:.1f} µm "
                            f"(bound {CLOSED_LOOP_BOUND_M * 1e6:g})")
        row["passed"] = not problems
        row["status"] = "agrees" if not problems else "fails: " + "; ".join(problems)
        rows.append(row)
    return rows


def replay_command(seed: int) -> str:
    """The command that runs crane `seed` through every check again (its experiments: their own commands)."""
    return (f"python -m acroboter.plant_fuzz --cranes 1 --crane-seed {seed} --workers 1 "
            f"--out results/plant_fuzz_cranes/replay-{crane_name(seed)}")

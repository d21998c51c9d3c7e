"""The Monte Carlo robustness grid: parameter ranges, seeded samples, the task that runs one sample.

A sample is a plant whose physical parameters (acroboter.model.physical names) are drawn uniformly within
the ranges around the spec's values, while every controller keeps the spec's model. Ranges come in
groups (`GROUPS`): relative for masses, inertias (the bodies' tensor entries and the winch drums'
reflected inertia) and dampings, absolute (mm) for the bodies' points and the fixed cables' lengths.

Sample i is drawn from numpy's generator seeded with (seed, i): any one sample can be drawn again
alone, and each is recorded with the exact `acroboter run --plant-param ...` line that re-runs it.
One uniform number is drawn per parameter name in `parameter_names` order whatever the ranges (a
parameter with a zero range stays at the spec's value), so narrowing one group does not move the
draws of the others. A draw the spec refuses (an inertia tensor that breaks the triangle inequality)
is redrawn from the same generator; `draws` counts the attempts.

`run_sample` is one dask task (or an in-process call): every method with and without integral
action on the sample's plant, one flat row each (COLUMNS), through `Crane.simulate` exactly as
`acroboter run` calls it, so the recorded command reproduces the row's figures.
"""

from __future__ import annotations

import math
import shlex
import time
from dataclasses import dataclass

from .grid import GridError, MissingLibraryError, crane_for_text, status_of, worker_name

DEFAULT_METHODS = ("mlm", "penalty", "iterative-3", "iterative-4", "iterative-5")
# group -> (help, unit, default half-width, relative?)
GROUPS = {
    "mass": ("body masses", "fraction", 0.10, True),
    "inertia": ("inertia tensor entries and winch drums' reflected inertia", "fraction", 0.20, True),
    "point": ("body point positions, per component", "mm", 5.0, False),
    "length": ("fixed cables' lengths", "mm", 2.0, False),
    "damping": ("body dampings", "fraction", 0.0, True),
}
MAX_DRAWS = 1000
# The paper's bounds (a run "succeeds" within both).
POSITION_BOUND_MM, YAW_BOUND_DEG = 5.3, 1.1
COLUMNS_HEAD = ["sample", "method", "ki", "status", "diverged", "max_position_error_mm", "rms_position_error_mm",
                "max_yaw_error_deg", "time_saturated_s", "max_position_error_settled_mm", "max_yaw_error_settled_deg",
                "success", "success_settled", "mass_error", "tracked_mass_error", "draws", "duration_s", "sim_wall_s",
                "worker"]
TIMING_COLUMNS = ("sim_wall_s", "worker")
# From this time on a run counts as settled: the integral action removes a model error in about 4 s
# (docs/integral_action.md); `max_position_error_settled_mm` is the max error after it.
SETTLE_S = 5.0


def group_of(name: str) -> str | None:
    """The range group of a plant parameter, None for those never perturbed (gravity)."""
    field = name.split(".", 1)[1] if "." in name else name
    if field == "mass":
        return "mass"
    if field.startswith("inertia.") or field == "winch.reflected_inertia":
        return "inertia"
    if field.startswith("points."):
        return "point"
    if field == "length":
        return "length"
    if field.startswith("damping."):
        return "damping"
    return None


def group_range(group: str):
    """The Range of a group's --<group>-range bounds (acroboter.model.ranges): relative groups as fractions from a
    tenth to ten times the model's value, the others a metre either way (in mm)."""
    import dataclasses

    from ..model.ranges import OFFSET_RANGE, RELATIVE_RANGE

    return dataclasses.replace(RELATIVE_RANGE if GROUPS[group][3] else OFFSET_RANGE, name=f"{group}_range")


def parse_range(text: str, group: str, what: str | None = None) -> tuple[float, float]:
    """'H' (±H) or 'LO:HI' for a group, both bounds in its range (group_range); relative groups in fractions,
    the others in mm. A ValueError starts with `what` (default --<group>-range; '' for none)."""
    what = f"--{group}-range" if what is None else what
    head = f"{what}: " if what else ""
    range_ = group_range(group)
    try:
        parts = [float(p) for p in str(text).split(":")]
    except ValueError:
        raise ValueError(f"{head}expected H (±H) or LO:HI with {range_.text()}, found '{text}'") from None
    if len(parts) not in (1, 2):
        raise ValueError(f"{head}expected H (±H) or LO:HI with {range_.text()}, found '{text}'")
    if len(parts) == 1:
        if (problem := range_.problem(parts[0])) is not None:
            raise ValueError(f"{head}{problem}")
        if parts[0] < 0:
            raise ValueError(f"{head}a half-width must be ≥ 0, found {parts[0]:g} (give LO:HI for a one-sided range, "
                             f"with {range_.text()})")
        parts = [-parts[0], parts[0]]
    for value in parts:
        if (problem := range_.problem(value)) is not None:
            raise ValueError(f"{head}{problem}" + (f" (±{text})" if ":" not in str(text) else ""))
    lo, hi = parts
    if lo > hi:
        raise ValueError(f"{head}LO:HI needs LO ≤ HI, found {lo:g} > {hi:g}")
    return lo, hi


def default_ranges() -> dict[str, tuple[float, float]]:
    return {g: (-h, h) for g, (_, _, h, _) in GROUPS.items()}


@dataclass(frozen=True)
class Sample:
    index: int
    seed: int
    params: dict  # name -> value, only the perturbed parameters (range width > 0)
    draws: int
    mass_error: float  # relative error of the plant's total body mass against the model's (SU + CC)
    tracked_mass_error: float  # the same for the tracked body alone (SU): what the PD law's sag follows


def draw_sample(spec, seed: int, index: int, ranges: dict[str, tuple[float, float]]) -> Sample:
    """Sample `index` of the study seeded `seed` (numpy default_rng((seed, index))), a valid crane."""
    import numpy as np

    from ..model.physical import PlantParameterError, parameter_names, parameter_values, with_parameters

    names, nominal = parameter_names(spec), parameter_values(spec)
    rng = np.random.default_rng((seed, index))
    for draw in range(1, MAX_DRAWS + 1):
        u = rng.random(len(names))
        params = {}
        for name, value, x in zip(names, nominal, u, strict=True):
            group = group_of(name)
            if group is None or ranges[group][0] == ranges[group][1] == 0.0:
                continue
            lo, hi = ranges[group]
            delta = lo + (hi - lo) * x
            params[name] = float(value * (1.0 + delta)) if GROUPS[group][3] else float(value + delta / 1000.0)
        try:
            with_parameters(spec, params)
        except PlantParameterError:
            continue
        def relative(masses, params=params):
            total = sum(nominal[names.index(n)] for n in masses)
            return float(sum(params.get(n, nominal[names.index(n)]) for n in masses) / total - 1.0)

        tracked = next(t.body for t in spec.task if t.kind == "position")
        return Sample(index, seed, params, draw, relative([n for n in names if group_of(n) == "mass"]),
                      relative([f"{tracked}.mass"]))
    raise ValueError(f"sample {index}: no valid crane in {MAX_DRAWS} draws: the ranges are too wide for this spec")


def recommended_ki(kp: float, kd: float) -> float:
    """docs/integral_action.md's choice: keep kp, kd and add a real pole at 30 % of the PD law's slowest
    pole, c = 0.3·(kd − √(kd² − kp²)) (0.3·kd when underdamped): ki = c(kp² − 2kd·c + c²); 18.375 for kp = kd = 5."""
    slowest = kd - math.sqrt(kd * kd - kp * kp) if kd >= kp else kd
    c = 0.3 * slowest
    return c * (kp * kp - 2.0 * kd * c + c * c)


def sensing_args(sensing: dict | None) -> list[str]:
    """The `acroboter run --sensing-*` options of a sensing override mapping (noise, delay_periods, seed)."""
    args: list[str] = []
    for group, std in (sensing or {}).get("noise", {}).items():
        args += ["--sensing-noise", f"{group}={std!r}"]
    for key, option in (("delay_periods", "--sensing-delay"), ("seed", "--sensing-seed")):
        if (sensing or {}).get(key) is not None:
            args += [option, str(sensing[key])]
    return args


def command(spec_path: str, sample: Sample, duration: float, method: str | None = None, ki: float | None = None,
            out: str | None = None, sensing: dict | None = None, fast: bool = False) -> str:
    """The `acroboter run` line that re-runs the sample (one method and ki, or every method at ki = 0)."""
    args = ["acroboter", "run", "--spec", str(spec_path), "--duration", repr(float(duration)), *sensing_args(sensing)]
    if fast:
        args.append("--fast")
    if method is not None:
        args += ["--method", method]
    if ki:
        args += ["--ki", repr(float(ki))]
    for name, value in sample.params.items():
        args += ["--plant-param", f"{name}={value!r}"]
    if out is not None:
        args += ["--out", out]
    return shlex.join(args)


def crashed_rows(sample, err: Exception) -> list[dict]:
    """A task that raised: one row saying so. A worker that cannot set up the model aborts the study
    (GridError; MissingLibraryError: no library there), as in the sweep."""
    from ..model.spec import SpecError
    from ..runtime.compiled import StaleModelError
    from ..sim.statics import EquilibriumError

    if isinstance(err, MissingLibraryError):
        raise err
    if isinstance(err, SpecError | EquilibriumError | StaleModelError | GridError):
        raise GridError(f"a worker could not set up the model: {err}") from None
    row = {c: None for c in COLUMNS_HEAD}
    row.update(sample=sample.index, status=f"error: task failed: {type(err).__name__}: {' '.join(str(err).split())}",
               diverged=False, success=False, success_settled=False, mass_error=sample.mass_error,
               tracked_mass_error=sample.tracked_mass_error, draws=sample.draws, **sample.params)
    return [row]


def columns(sample: Sample) -> list[str]:
    return COLUMNS_HEAD + list(sample.params)


def success(row: dict, settled: bool = False) -> bool:
    """Within the paper's bounds over the whole run (settled: from SETTLE_S on; None if the run is shorter)."""
    if row.get("status") != "ok":
        return False
    pos, yaw = ((row.get("max_position_error_settled_mm"), row.get("max_yaw_error_settled_deg")) if settled
                else (row["max_position_error_mm"], row["max_yaw_error_deg"]))
    if pos is None:
        return None
    return pos <= POSITION_BOUND_MM and (yaw is None or abs(yaw) <= YAW_BOUND_DEG)


# ---------------------------------------------------------------------------------------------------
# The task

def run_sample(spec_text: str, source: str, sample: Sample, duration: float, methods: tuple[str, ...],
               kis: tuple[float, ...], sensing=None, fast: bool = False) -> list[dict]:
    """Every (method, ki) of one sample on its plant: one row each, in (method, ki) order. A run that
    fails numerically is a row whose status says how; only a worker that cannot load the model raises.

    `sensing`: passed on as `Crane.simulate(sensing=...)` when given (measurement noise/delay, where
    the installed package has it); None runs with perfect measurements. `fast`: the controllers' fast path
    (docs/fast-path.md; its libraries built in the cache beforehand: acroboter.studies.robustness_study.prebuild)."""
    from numpy.linalg import LinAlgError

    from ..control.controllers import SingularSystemError
    from ..control.recovery import RecoveryError
    from ..sim.plant import SimulationError

    crane = crane_for_text(spec_text, source)  # never compiles: MissingLibraryError if the worker has no library
    worker = worker_name()
    extra = {} if sensing is None else {"sensing": sensing}
    rows = []
    for method in methods:
        for ki in kis:
            row = {c: None for c in COLUMNS_HEAD}
            row |= {"sample": sample.index, "method": method, "ki": ki, "mass_error": sample.mass_error,
                   "tracked_mass_error": sample.tracked_mass_error, "draws": sample.draws, "duration_s": duration,
                   "worker": worker, **sample.params}
            t0 = time.perf_counter()
            try:
                result = crane.simulate(method, duration=duration, plant_params=sample.params, ki=ki, fast=fast,
                                        **extra)
                s = result.summary()
                row.update(max_position_error_mm=s["max_position_error_mm"],
                           rms_position_error_mm=s["rms_position_error_mm"],
                           max_yaw_error_deg=s["max_yaw_error_deg"], time_saturated_s=s["time_saturated_s"])
                late = result.time >= SETTLE_S
                if late.any():
                    row["max_position_error_settled_mm"] = float(result.position_error_mm[late].max())
                    yaw = result.yaw_error_deg
                    row["max_yaw_error_settled_deg"] = 0.0 if yaw is None else float(abs(yaw[late]).max())
                diverged = result.diverged_at is not None
                row["status"] = (f"diverged at t = {result.diverged_at:.2f} s ({result.run.divergence})"
                                 if diverged else "ok")
            except (SingularSystemError, SimulationError, RecoveryError, LinAlgError, ValueError,
                    FloatingPointError, ArithmeticError) as err:
                row["status"] = status_of(err)
            row["diverged"] = row["status"].startswith("diverged")
            row["success"] = success(row)
            row["success_settled"] = success(row, settled=True)
            row["sim_wall_s"] = time.perf_counter() - t0
            rows.append(row)
    return rows

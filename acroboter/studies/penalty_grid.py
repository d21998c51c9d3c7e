"""The penalty-number grid: its cases, the task that runs one case, and the row it returns.

A case is a method (MLM, or the penalty method with N iterations: N = 1 plain, N > 1 iterative),
its penalty numbers α̃ (geometric constraints) and α̂ (servo-constraints) and the constraint
penalty's natural frequency Ω. `run_case` simulates one case's closed loop and returns one flat row
(COLUMNS): the run's tracking figures, the plant's constraint drift, and, at states sampled along
the run, the condition number of the penalty matrix A = M + α̃ φ_qᵀφ_q + α̂ σ_qᵀσ_q and how far the
commanded acceleration q̈ violates the constraint and servo-constraint acceleration equations:
|φ_q q̈ + ρ| = |λ|/α̃ and |σ_q q̈ + ρ_s| = |λ̂|/α̂, the softness of the penalty (zero for MLM up to
round-off). It runs on a dask worker (acroboter.studies.grid.run_cases) or in-process alike.
"""

from __future__ import annotations

import functools
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

from ..model.spec import MAX_ITERATIONS
from .grid import GridError, MissingLibraryError, crane_for_text, read_rows, run_cases, status_of, worker_name

ALPHA_MODES = ("tied", "geometric", "servo", "grid")
COND_SAMPLES = 10

COLUMNS = [
    "method", "iterations", "alpha_geometric", "alpha_servo", "omega", "mu", "kp", "kd", "duration_s", "status",
    "max_position_error_mm", "rms_position_error_mm", "max_yaw_error_deg", "max_tilt_deg",
    "max_constraint_violation", "min_winch_tension_N", "max_winch_tension_N", "median_control_step_us",
    "cond_penalty_matrix", "max_constraint_accel_residual", "max_servo_accel_residual", "sim_wall_s", "worker",
]
SUMMARY_COLUMNS = ("max_position_error_mm", "rms_position_error_mm", "max_yaw_error_deg", "max_tilt_deg",
                   "max_constraint_violation", "min_winch_tension_N", "max_winch_tension_N")


@dataclass(frozen=True)
class Case:
    """One grid point. MLM has no penalty numbers, Ω or iterations (None)."""

    method: str
    alpha_geometric: float | None = None
    alpha_servo: float | None = None
    omega: float | None = None
    iterations: int | None = None


def parse_iterations(text: str) -> list[int]:
    try:
        values = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise ValueError(f"--iterations takes comma-separated whole numbers, found '{text}'") from None
    if not values or any(not 1 <= v <= MAX_ITERATIONS for v in values):
        raise ValueError(f"--iterations: every count must be between 1 (the plain penalty method) and "
                         f"{MAX_ITERATIONS}, found '{text}'")
    return list(dict.fromkeys(values))


def method_name(iterations: int) -> str:
    return "penalty" if iterations == 1 else f"iterative-{iterations}"


def make_grid(alphas: list[float], omegas: list[float], iterations: list[int], alpha_mode: str = "tied",
              fixed_geometric: float = 1e7, fixed_servo: float = 1e7, mlm: bool = True) -> list[Case]:
    """MLM reference first, then every (iterations, α̃, α̂, Ω).

    alpha_mode: 'tied' α̃ = α̂ = α; 'geometric' sweeps α̃ with α̂ = fixed_servo; 'servo' sweeps α̂ with
    α̃ = fixed_geometric; 'grid' every (α̃, α̂) pair of the values.
    """
    if alpha_mode == "tied":
        pairs = [(a, a) for a in alphas]
    elif alpha_mode == "geometric":
        pairs = [(a, fixed_servo) for a in alphas]
    elif alpha_mode == "servo":
        pairs = [(fixed_geometric, a) for a in alphas]
    elif alpha_mode == "grid":
        pairs = [(a, b) for a in alphas for b in alphas]
    else:
        raise ValueError(f"unknown alpha mode '{alpha_mode}': choose one of {', '.join(ALPHA_MODES)}")
    cases = [Case("mlm")] if mlm else []
    cases += [Case(method_name(n), ag, asv, om, n) for n in iterations for ag, asv in pairs for om in omegas]
    return cases


# The swept axis of each alpha mode: its column, its axis label and its symbol in the findings.


def x_key(alpha_mode: str) -> str:
    return "alpha_servo" if alpha_mode == "servo" else "alpha_geometric"


def x_label(alpha_mode: str) -> str:
    return {"tied": "penalty number α = α̃ = α̂", "geometric": "α̃ (constraint penalty)",
            "servo": "α̂ (servo penalty)", "grid": "α̃ (constraint penalty)"}[alpha_mode]


def x_symbol(alpha_mode: str) -> str:
    return {"tied": "α", "geometric": "α̃", "servo": "α̂", "grid": "α̃"}[alpha_mode]


# ---------------------------------------------------------------------------------------------------
# The task


def _probe(crane, method: str, overrides: dict, result, count: int) -> tuple[float, float, float]:
    """At `count` recorded states: max cond(A), max |φ_q q̈ + ρ| and max |σ_q q̈ + ρ_s| of the controller's q̈.

    The controller (the run's method and gains, `crane.controller`) recomputes its q̈ at each recorded state; A,
    φ_q, ρ, σ_q, ρ_s are the generated penalty_terms evaluated there with the run's gains, on working arrays of
    their own (`crane.model.data()`). Without a run (it failed): A at the start state only.
    """
    import numpy as np

    data = crane.model.data()
    fn, gains = data.functions["penalty_terms"], crane.gains(**overrides)
    out = fn.outputs
    data.p[:] = gains.parameter_vector(data.layout.k)
    controller = crane.controller(method, **overrides) if result is not None else None
    penalty = method != "mlm"
    cond = res_phi = res_sigma = -np.inf
    samples = len(result.time) if result is not None else 1
    start = crane.equilibrium().q
    for k in np.unique(np.linspace(0, samples - 1, count).round().astype(int)):
        if result is None:  # the run failed: A at the start state only
            q, qd, t = start, np.zeros_like(start), 0.0
        else:
            q, qd, t = result.run.q[k], result.run.qd[k], float(result.time[k])
        qdd = None
        if controller is not None:
            controller.step(q, qd, t)
            qdd = controller.qdd
        data.q[:], data.qd[:], data.signals[:] = q, qd, crane.path.flat(t)
        fn.call()
        if penalty:
            cond = max(cond, float(np.linalg.cond(out["penalty_matrix"])))
        if qdd is not None:
            res_phi = max(res_phi, float(np.abs(out["phi_q"] @ qdd + out["rho"]).max()))
            res_sigma = max(res_sigma, float(np.abs(out["sigma_q"] @ qdd + out["rho_s"]).max()))
    nan = float("nan")
    return (cond if cond > -np.inf else nan, res_phi if res_phi > -np.inf else nan,
            res_sigma if res_sigma > -np.inf else nan)


def run_case(spec_text: str, source: str, case: Case, duration: float | None, cond_samples: int = COND_SAMPLES,
             kp: float | None = None, kd: float | None = None, mu: float | None = None) -> dict:
    """One grid point: simulated through the library (`Crane.simulate`, the crane cached per worker thread) and
    summarized. Returns a flat row (COLUMNS); never raises for a run that fails numerically (status says how), only
    for a worker that cannot run the model at all."""
    from numpy.linalg import LinAlgError

    from ..control.controllers import SingularSystemError
    from ..control.recovery import RecoveryError
    from ..sim.plant import SimulationError

    worker = worker_name()
    crane = crane_for_text(spec_text, source)  # never compiles: MissingLibraryError if the worker has no library
    overrides = {"kp": kp, "kd": kd, "mu": mu, "alpha_geometric": case.alpha_geometric,
                 "alpha_servo": case.alpha_servo, "omega": case.omega}
    gains = crane.gains(**overrides)
    duration = crane.path.duration if duration is None else duration
    row = {c: None for c in COLUMNS}
    row.update(asdict(case))
    row.update(mu=gains.mu if case.method != "mlm" else None, kp=gains.kp, kd=gains.kd, duration_s=duration,
               worker=worker)
    result = None
    t0 = time.perf_counter()
    try:
        result = crane.simulate(case.method, duration=duration, warm_up=0, **overrides)
        if result.diverged_at is not None:  # stopped early: its figures would describe a broken run
            row["status"] = f"diverged at t = {result.diverged_at:.2f} s ({result.run.divergence})"
            result = None
        else:
            summary = result.summary()
            row.update({k: summary[k] for k in SUMMARY_COLUMNS})
            row["median_control_step_us"] = summary["control_step_us"]["median"]
            row["status"] = "ok"
    except (SingularSystemError, SimulationError, RecoveryError, LinAlgError, ValueError, FloatingPointError,
            ArithmeticError) as err:
        row["status"] = status_of(err)
        result = None
    row["sim_wall_s"] = time.perf_counter() - t0
    try:
        cond, res_phi, res_sigma = _probe(crane, case.method, overrides, result, cond_samples)
    except (SingularSystemError, LinAlgError, ValueError, FloatingPointError) as err:
        cond = res_phi = res_sigma = float("nan")
        if row["status"] == "ok":
            row["status"] = f"error: probing the penalty matrix failed: {' '.join(str(err).split())}"
    row.update(cond_penalty_matrix=cond, max_constraint_accel_residual=res_phi, max_servo_accel_residual=res_sigma)
    return row


def crashed_row(case: Case, err: Exception) -> dict:
    """The row of a task that raised (a worker died, a bug): its status says so. A worker that cannot
    set up the model at all aborts the grid instead (GridError): every other task would fail alike."""
    from ..model.spec import SpecError
    from ..runtime.compiled import StaleModelError
    from ..sim.statics import EquilibriumError

    if isinstance(err, MissingLibraryError):
        raise err
    if isinstance(err, SpecError | EquilibriumError | StaleModelError | GridError):
        raise GridError(f"a worker could not set up the model: {err}") from None
    row = {c: None for c in COLUMNS}
    row.update(asdict(case))
    row["status"] = f"error: task failed: {type(err).__name__}: {' '.join(str(err).split())}"
    return row


def read_csv(path: Path) -> list[dict]:
    """Rows of a sweep.csv, typed as run_case returns them (empty cells: None)."""
    return read_rows(path, ints={"iterations"}, strs={"method", "status", "worker"})


def run_sweep(client, spec_path: Path, cases: list[Case], duration: float | None, progress: bool = False,
              cond_samples: int = COND_SAMPLES, kp: float | None = None, kd: float | None = None,
              mu: float | None = None) -> list[dict]:
    """Run every case on `client` (None: in this process), the rows in grid order (progress bar over
    completed tasks). A task that crashed is a row with its status; a worker that cannot set up the
    model at all raises GridError (MissingLibraryError: no library there)."""
    from tqdm import tqdm

    # The spec travels as text: a worker on another machine need not see the client's file system.
    task = functools.partial(run_case, Path(spec_path).read_text(encoding="utf-8"), str(spec_path),
                             duration=duration, cond_samples=cond_samples, kp=kp, kd=kd, mu=mu)
    with tqdm(total=len(cases), unit="run", desc="sweep", file=sys.stderr, disable=not progress,
              smoothing=0.0) as bar:

        def done(case: Case, row: dict) -> None:
            if case.method != "mlm":
                bar.set_postfix_str(f"{case.method} α̃={case.alpha_geometric:.0e} α̂={case.alpha_servo:.0e} "
                                    f"Ω={case.omega:g}", refresh=False)
            bar.update(1)

        return run_cases(task, cases, client, name="sweep", on_done=done, on_error=crashed_row)

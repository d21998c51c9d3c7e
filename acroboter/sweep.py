"""Penalty-number study on Dask: `python -m acroboter.sweep` (see --help).

The grid: the penalty numbers α (by default α̃ = α̂ = α, one value per decade from 1e1 to 1e16: the
usual range 1e3..1e12 and enough beyond it on both sides to see each method break down), the
constraint penalty's natural frequency Ω, and the methods penalty and iterative-N, plus one MLM
reference run (MLM has no penalty numbers). Every grid point is one closed-loop simulation of the
spec's path, run as one task on a dask.distributed cluster: by default a LocalCluster of worker
processes on 127.0.0.1, with --scheduler ADDRESS a running cluster (its workers need this package
and the same checkout, with the model library already built: tasks never compile).

Each task returns one flat row (see COLUMNS): the run's tracking figures, the plant's constraint
drift, and, at states sampled along the run, the condition number of the penalty matrix
A = M + α̃ φ_qᵀφ_q + α̂ σ_qᵀσ_q and how far the commanded acceleration q̈ violates the constraint and
servo-constraint acceleration equations: |φ_q q̈ + ρ| = |λ|/α̃ and |σ_q q̈ + ρ_s| = |λ̂|/α̂, the
softness of the penalty (zero for MLM up to round-off).

Writes <out>/sweep.csv and the figures sweep_tracking_error.png, sweep_constraints.png and
sweep_condition.png; prints a table of the tracking error and the α range over which each method
stays within a factor (--tolerance, 2) of MLM's error, and how it breaks down outside it.
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import math
import re
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path

from .entry import check_out_folder, guarded, number, positive, whole
from .locations import example_spec
from .spec import MAX_CONTROL_STEPS, MAX_ITERATIONS

DEFAULT_SPEC = example_spec("acroboter")
DEFAULT_ALPHAS = "1e1:1e16"
DEFAULT_OMEGAS = "5,10,20"
DEFAULT_ITERATIONS = "1,3,5,10"
ALPHA_MODES = ("tied", "geometric", "servo", "grid")
COND_SAMPLES = 10
# Condition number of A above which a run outside the good range is called ill-conditioned (eps · cond > 0.2).
ILL_CONDITIONED = 1e15
# Above this |φ_q q̈ + ρ| or |σ_q q̈ + ρ_s| a run outside the good range is called soft (penalty too small).
SOFT_RESIDUAL = 1e-8

COLUMNS = [
    "method", "iterations", "alpha_geometric", "alpha_servo", "omega", "mu", "kp", "kd", "duration_s", "status",
    "max_position_error_mm", "rms_position_error_mm", "max_yaw_error_deg", "max_tilt_deg",
    "max_constraint_violation", "min_winch_tension_N", "max_winch_tension_N", "median_control_step_us",
    "cond_penalty_matrix", "max_constraint_accel_residual", "max_servo_accel_residual", "sim_wall_s", "worker",
]


# At most this many values per grid axis and runs per sweep (checked while parsing, before any work).
MAX_GRID_VALUES = 1000
MAX_RUNS = 20_000


class SweepError(RuntimeError):
    """The sweep cannot run at all (bad spec, stale or missing model library, no cluster)."""


class MissingLibraryError(SweepError):
    """A worker found no compiled model library: it must not build one."""


# ---------------------------------------------------------------------------------------------------
# The grid


@dataclass(frozen=True)
class Case:
    """One grid point. MLM has no penalty numbers, Ω or iterations (None)."""

    method: str
    alpha_geometric: float | None = None
    alpha_servo: float | None = None
    omega: float | None = None
    iterations: int | None = None


def parse_values(text: str, what: str = "values") -> list[float]:
    """Comma-separated numbers, each a value or a log range START:STOP[:PER_DECADE] (default 1 per decade)."""
    values: list[float] = []
    for item in (s.strip() for s in text.split(",")):
        if not item:
            continue
        parts = item.split(":")
        try:
            nums = [float(p) for p in parts]
        except ValueError:
            raise ValueError(f"{what}: expected numbers or START:STOP[:PER_DECADE] ranges, found '{item}'") from None
        if len(nums) == 1:
            values.append(nums[0])
            continue
        if len(nums) > 3 or nums[0] <= 0 or nums[1] < nums[0]:
            raise ValueError(f"{what}: a range is START:STOP[:PER_DECADE] with 0 < START <= STOP, found '{item}'")
        per_decade = nums[2] if len(nums) == 3 else 1.0
        if per_decade <= 0 or per_decade != int(per_decade):
            raise ValueError(f"{what}: points per decade must be a whole number >= 1, found '{item}'")
        lo, hi = math.log10(nums[0]), math.log10(nums[1])
        count = int(round((hi - lo) * per_decade)) + 1
        if count + len(values) > MAX_GRID_VALUES:
            raise ValueError(f"{what}: at most {MAX_GRID_VALUES} values, found a range of {count} in '{item}'")
        values += [float(f"{10 ** (lo + i / per_decade):.12g}") for i in range(count)]
    if not values:
        raise ValueError(f"{what}: no values given")
    if any(not math.isfinite(v) or v <= 0 for v in values):
        raise ValueError(f"{what}: every value must be positive and finite, found {text!r}")
    return list(dict.fromkeys(values))


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


# ---------------------------------------------------------------------------------------------------
# The task (runs on a worker)


@dataclass
class _Context:
    spec: object
    model: object
    path: object
    q0: object
    plant: object
    scenario: object


_LOCAL = threading.local()  # one model per worker thread: the model's input buffers are not thread-safe


def _context(spec_text: str, source: str) -> _Context:
    key = hashlib.sha256(spec_text.encode()).hexdigest()
    cache = getattr(_LOCAL, "contexts", None)
    if cache is None:
        cache = _LOCAL.contexts = {}
    if key not in cache:
        import tomllib

        from .cache import load_model
        from .compiled import NotBuiltError
        from .simulation import Scenario, setup_default
        from .spec import parse_spec
        from .statics import desired_path, solve_equilibrium

        spec = parse_spec(tomllib.loads(spec_text), source)
        try:
            model = load_model(spec, build=False)  # a task never generates or compiles
        except NotBuiltError as err:
            import socket

            raise MissingLibraryError(
                f"worker on {socket.gethostname()}: {err}; sweep tasks never compile. Build it on every worker "
                f"machine (`acroboter build {spec.name}`, or run the spec once there), then rerun the sweep."
            ) from None
        path = desired_path(model)
        cache[key] = _Context(spec, model, path, solve_equilibrium(model, path).q, setup_default(model, path),
                              Scenario.from_model(model))
    return cache[key]


def _status_of(err: Exception) -> str:
    from .plant import SimulationError

    text = " ".join(str(err).split())
    if isinstance(err, SimulationError):
        found = re.search(r"at t = ([-+0-9.eE]+) s:? ?(.*)", text)
        if found:
            why = found.group(2).strip(" ()")
            return f"diverged at t = {found.group(1)} s" + (f" ({why})" if why else "")
    return f"error: {text}"


def _probe(ctx: _Context, controller, gains, result, count: int) -> tuple[float, float, float]:
    """At `count` recorded states: max cond(A), max |φ_q q̈ + ρ| and max |σ_q q̈ + ρ_s| of the controller's q̈.

    The controller factors penalty_terms' output A in place, so A is re-evaluated here after each
    controller call, with this run's gains in the parameter buffer.
    """
    import numpy as np

    model, fn = ctx.model, ctx.model.functions["penalty_terms"]
    out, params = fn.outputs, gains.parameter_vector()
    penalty = controller is not None and controller.name != "mlm"
    cond = res_phi = res_sigma = -np.inf
    samples = len(result.t) if result is not None else 1
    for k in np.unique(np.linspace(0, samples - 1, count).round().astype(int)):
        if result is None:  # the run failed: A at the start state only
            q, qd, t = ctx.q0, np.zeros_like(ctx.q0), 0.0
        else:
            q, qd, t = result.q[k], result.qd[k], float(result.t[k])
        qdd = None
        if result is not None and controller is not None:
            controller.compute(q, qd, t)
            qdd = np.array(controller.qdd, copy=True)
        model.q[:] = q
        model.qd[:] = qd
        model.signals[:] = ctx.path.flat(t)
        model.p[:] = params
        model.parameters_owner = None  # a controller reloads its own gains on its next call
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
    """One grid point: simulate and summarize. Returns a flat row (COLUMNS); never raises for a run that
    fails numerically (status says how), only for a worker that cannot run the model at all."""
    from numpy.linalg import LinAlgError

    from .controllers import Gains, SingularSystemError, make_controller
    from .plant import SimulationError
    from .recovery import RecoveryError
    from .simulation import simulate, summarize

    try:
        from distributed import get_worker

        worker = get_worker().address
    except (ImportError, ValueError):
        worker = "local"
    ctx = _context(spec_text, source)
    spec = ctx.spec
    gains = Gains.from_spec(spec, kp=kp, kd=kd, mu=mu, alpha_geometric=case.alpha_geometric,
                            alpha_servo=case.alpha_servo, omega=case.omega)
    duration = ctx.path.duration if duration is None else duration
    row = {c: None for c in COLUMNS}
    row.update(asdict(case))
    row.update(mu=gains.mu if case.method != "mlm" else None, kp=gains.kp, kd=gains.kd, duration_s=duration,
               worker=worker)
    controller = result = None
    t0 = time.perf_counter()
    try:
        controller = make_controller(case.method, ctx.model, ctx.path, gains)
        result = simulate(ctx.model, ctx.path, controller, ctx.plant, ctx.q0, duration, spec.controller.rate_hz,
                          spec.simulation.step, allow_divergence=True)
        if result.diverged_at is not None:  # stopped early: its figures would describe a broken run
            row["status"] = f"diverged at t = {result.diverged_at:.2f} s ({result.divergence})"
            result = None
        else:
            summary = summarize(result, ctx.scenario, ctx.model.layout)
            row.update({k: summary[k] for k in ("max_position_error_mm", "rms_position_error_mm",
                                                "max_yaw_error_deg", "max_tilt_deg", "max_constraint_violation",
                                                "min_winch_tension_N", "max_winch_tension_N")})
            row["median_control_step_us"] = summary["control_step_us"]["median"]
            row["status"] = "ok"
    except (SingularSystemError, SimulationError, RecoveryError, LinAlgError, ValueError, FloatingPointError,
            ArithmeticError) as err:
        row["status"] = _status_of(err)
        result = None
    row["sim_wall_s"] = time.perf_counter() - t0
    try:
        cond, res_phi, res_sigma = _probe(ctx, controller, gains, result, cond_samples)
    except (SingularSystemError, LinAlgError, ValueError, FloatingPointError) as err:
        cond = res_phi = res_sigma = float("nan")
        if row["status"] == "ok":
            row["status"] = f"error: probing the penalty matrix failed: {' '.join(str(err).split())}"
    row.update(cond_penalty_matrix=cond, max_constraint_accel_residual=res_phi, max_servo_accel_residual=res_sigma)
    return row


# ---------------------------------------------------------------------------------------------------
# The cluster


@contextmanager
def open_client(scheduler: str | None = None, workers: int = 2, connect_timeout: float = 10.0) -> Iterator:
    """A dask.distributed Client: to the scheduler at `scheduler`, or to a LocalCluster of `workers`
    single-threaded worker processes on 127.0.0.1 (closed on exit)."""
    import logging

    from distributed import Client, LocalCluster

    if scheduler:
        try:
            client = Client(scheduler, timeout=connect_timeout)
        except (OSError, TimeoutError, ValueError) as err:
            raise SweepError(
                f"cannot connect to the Dask scheduler at '{scheduler}' within {connect_timeout:g} s "
                f"({type(err).__name__}: {' '.join(str(err).split())}): is a scheduler running there "
                "(`dask scheduler`)? Or leave out --scheduler to use a local cluster."
            ) from None
        with client:
            yield client
        return
    if workers < 1:
        raise SweepError("the local cluster needs at least one worker")
    with (
        LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                     dashboard_address=None, silence_logs=logging.ERROR) as cluster,
        Client(cluster) as client,
    ):
        yield client


def _worker_count(client) -> int:
    try:
        info = client.scheduler_info(n_workers=-1)  # newer distributed lists only a few workers by default
    except TypeError:
        info = client.scheduler_info()
    return len(info["workers"])


@dataclass
class SweepResult:
    rows: list[dict]
    wall_s: float
    workers: int
    files: list[Path] = field(default_factory=list)


def run_sweep(client, spec_path: Path, cases: list[Case], duration: float | None, progress: bool = False,
              cond_samples: int = COND_SAMPLES, kp: float | None = None, kd: float | None = None,
              mu: float | None = None) -> list[dict]:
    """Submit every case to `client`, gather the rows in grid order (progress bar over completed tasks)."""
    from distributed import as_completed
    from tqdm import tqdm

    spec_text = Path(spec_path).read_text(encoding="utf-8")
    source = str(spec_path)
    futures = {}
    for i, case in enumerate(cases):
        fut = client.submit(run_case, spec_text, source, case, duration, cond_samples, kp, kd, mu, pure=False,
                            key=f"sweep-{i}-{case.method}-{case.alpha_geometric}-{case.alpha_servo}-{case.omega}-"
                                f"{time.time_ns()}")
        futures[fut] = (i, case)
    rows: list[dict | None] = [None] * len(cases)
    try:
        with tqdm(total=len(cases), unit="run", desc="sweep", file=sys.stderr, disable=not progress,
                  smoothing=0.0) as bar:
            for fut in as_completed(futures):
                i, case = futures[fut]
                try:
                    rows[i] = fut.result()
                except MissingLibraryError:
                    raise
                except Exception as err:  # noqa: BLE001 - a task crash (worker died, bug) becomes the row's status
                    from .compiled import StaleModelError
                    from .spec import SpecError
                    from .statics import EquilibriumError

                    if isinstance(err, SpecError | EquilibriumError | StaleModelError | SweepError):
                        raise SweepError(f"a worker could not set up the model: {err}") from None
                    row = {c: None for c in COLUMNS}
                    row.update(asdict(case))
                    row["status"] = f"error: task failed: {type(err).__name__}: {' '.join(str(err).split())}"
                    rows[i] = row
                if case.method != "mlm":
                    bar.set_postfix_str(f"{case.method} α̃={case.alpha_geometric:.0e} α̂={case.alpha_servo:.0e} "
                                        f"Ω={case.omega:g}", refresh=False)
                bar.update(1)
    finally:
        client.cancel(list(futures))
    return rows  # type: ignore[return-value]


def sweep(spec_path: Path = DEFAULT_SPEC, *, alphas: list[float] | None = None, omegas: list[float] | None = None,
          iterations: list[int] | None = None, alpha_mode: str = "tied", duration: float | None = None,
          workers: int = 2, scheduler: str | None = None, connect_timeout: float = 10.0, out: Path | None = None,
          plots: bool = True, progress: bool = False, tolerance: float = 2.0, kp: float | None = None,
          kd: float | None = None, mu: float | None = None) -> SweepResult:
    """The whole study as a function: build the model once here, run the grid on the cluster, and
    (with `out`) write sweep.csv and the figures. Raises SweepError when it cannot run at all."""
    from .cache import load_model
    from .compiled import StaleModelError
    from .spec import SpecError, load_spec

    alphas = alphas or parse_values(DEFAULT_ALPHAS)
    omegas = omegas or parse_values(DEFAULT_OMEGAS)
    iterations = iterations or parse_iterations(DEFAULT_ITERATIONS)
    try:
        spec = load_spec(spec_path)
        load_model(spec)  # builds the library here if missing: the tasks only load it
    except (SpecError, StaleModelError) as err:
        raise SweepError(str(err)) from None
    rate = spec.controller.rate_hz
    if duration is not None and not 1 <= round(duration * rate) <= MAX_CONTROL_STEPS:
        raise SweepError(f"--duration {duration:g} s is {round(duration * rate)} control steps at {rate:g} Hz: give "
                         f"between one ({1 / rate:g} s) and {MAX_CONTROL_STEPS}")
    pen = spec.controller.penalty
    cases = make_grid(alphas, omegas, iterations, alpha_mode, pen.alpha_geometric, pen.alpha_servo)
    t0 = time.perf_counter()
    with open_client(scheduler, workers, connect_timeout) as client:
        n_workers = _worker_count(client) if scheduler else workers
        rows = run_sweep(client, Path(spec_path), cases, duration, progress=progress, kp=kp, kd=kd, mu=mu)
    result = SweepResult(rows, time.perf_counter() - t0, n_workers)
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        write_csv(out / "sweep.csv", rows)
        result.files.append(out / "sweep.csv")
        if plots:
            result.files += write_figures(out, rows, alpha_mode, tolerance)
    return result


# ---------------------------------------------------------------------------------------------------
# Reports


def write_csv(path: Path, rows: list[dict]) -> None:
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS, extrasaction="ignore")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: ("" if row.get(k) is None else row[k]) for k in COLUMNS})


def read_csv(path: Path) -> list[dict]:
    """Rows of a sweep.csv, typed as the tasks return them (empty cells: None)."""
    ints, strs = {"iterations"}, {"method", "status", "worker"}
    rows = []
    with Path(path).open(newline="") as f:
        for raw in csv.DictReader(f):
            rows.append({k: (None if v == "" else v if k in strs else int(v) if k in ints else float(v))
                         for k, v in raw.items()})
    return rows


def _x_key(alpha_mode: str) -> str:
    return "alpha_servo" if alpha_mode == "servo" else "alpha_geometric"


def _x_label(alpha_mode: str) -> str:
    return {"tied": "penalty number α = α̃ = α̂", "geometric": "α̃ (constraint penalty)",
            "servo": "α̂ (servo penalty)", "grid": "α̃ (constraint penalty)"}[alpha_mode]


def _methods(rows: list[dict]) -> list[str]:
    penalty = sorted({r["iterations"] for r in rows if r["method"] != "mlm" and r["iterations"] is not None})
    return [method_name(n) for n in penalty]


def _mlm(rows: list[dict]) -> dict | None:
    return next((r for r in rows if r["method"] == "mlm"), None)


def _ok(row: dict) -> bool:
    return row.get("status") == "ok"


def _err(row: dict) -> float:
    return row["max_position_error_mm"] if _ok(row) and row["max_position_error_mm"] is not None else math.nan


def format_table(rows: list[dict], alpha_mode: str = "tied") -> str:
    """Max position error (mm) per method and Ω (and α̂ in grid mode) against the swept α."""
    xk = _x_key(alpha_mode)
    xs = sorted({r[xk] for r in rows if r["method"] != "mlm"})
    label = "method         Ω" + ("      α̂" if alpha_mode == "grid" else "")
    width = 16 + (8 if alpha_mode == "grid" else 0)
    head = f"{label:<{width}}" + "".join(f"{x:>9.0e}" for x in xs)
    lines = [f"max position error (mm) vs {_x_label(alpha_mode)}; div = diverged, err = error", head,
             "-" * len(head)]
    groups: dict[tuple, dict] = {}
    for r in rows:
        if r["method"] == "mlm":
            continue
        g = (r["iterations"], r["omega"], r["alpha_servo"] if alpha_mode == "grid" else None)
        groups.setdefault(g, {})[r[xk]] = r
    for (n, omega, aserv), by_x in sorted(groups.items()):
        name = f"{method_name(n):<12} {omega:>3g}" + (f" {aserv:7.0e}" if alpha_mode == "grid" else "")
        cells = []
        for x in xs:
            r = by_x.get(x)
            if r is None:
                cells.append(f"{'':>9}")
            elif _ok(r):
                cells.append(f"{r['max_position_error_mm']:9.3g}")
            else:
                cells.append(f"{'div' if r['status'].startswith('diverged') else 'err':>9}")
        lines.append(f"{name:<{width}}" + "".join(cells))
    ref = _mlm(rows)
    if ref is not None:
        value = f"{ref['max_position_error_mm']:.3g} mm" if _ok(ref) else ref["status"]
        lines.append(f"mlm (no penalty numbers): {value}")
    return "\n".join(lines)


def _fmt_range(values: list[float], fmt: str, unit: str = "") -> str:
    lo, hi = min(values), max(values)
    text = format(lo, fmt) if lo == hi or format(lo, fmt) == format(hi, fmt) else f"{lo:{fmt}}..{hi:{fmt}}"
    return text + unit


def _category(row: dict) -> str:
    """How a run outside the good range fails: diverged, not-pd, error, ill, soft or large."""
    status = row.get("status") or ""
    if status.startswith("diverged"):
        return "diverged"
    if "not positive definite" in status:
        return "not-pd"
    if not _ok(row):
        return "error"
    cond = row.get("cond_penalty_matrix")
    if cond is not None and cond > ILL_CONDITIONED:
        return "ill"
    soft = max(row.get("max_servo_accel_residual") or 0.0, row.get("max_constraint_accel_residual") or 0.0)
    return "soft" if soft > SOFT_RESIDUAL else "large"


def _describe(segment: list[dict], ref_err: float, xk: str, symbol: str = "α") -> str:
    kind = _category(segment[0])
    where = f"{symbol} = " + _fmt_range([r[xk] for r in segment], ".0e")
    errs = [r["max_position_error_mm"] for r in segment if _ok(r)]
    err = (f"error {_fmt_range(errs, '.3g', ' mm')} = {_fmt_range([e / ref_err for e in errs], '.3g')}x MLM"
           if errs else "")
    conds = [r["cond_penalty_matrix"] for r in segment if r.get("cond_penalty_matrix") is not None
             and math.isfinite(r["cond_penalty_matrix"])]
    if kind == "diverged":
        times = [float(re.search(r"t = ([-+0-9.eE]+)", r["status"]).group(1)) for r in segment]
        whys = sorted({m.group(1) for r in segment if (m := re.search(r"\((.*)\)$", r["status"]))})
        why = f": {'; '.join(whys)}" if whys else ""
        return f"the loop diverges (at t = {_fmt_range(times, 'g', ' s')}{why}) at {where}"
    if kind == "not-pd":
        cond = f"; cond(A) {_fmt_range(conds, '.1e')} at the start, beyond 1/eps" if conds else ""
        return f"A is not positive definite in floating point (Cholesky fails{cond}) at {where}"
    if kind == "error":
        return f"{segment[0]['status'][:100]} at {where}"
    if kind == "ill":
        return f"ill-conditioned A (cond {_fmt_range(conds, '.1e')}): {err} at {where}"
    if kind == "soft":
        servo = max(r.get("max_servo_accel_residual") or 0.0 for r in segment)
        geo = max(r.get("max_constraint_accel_residual") or 0.0 for r in segment)
        return (f"soft penalty (commanded q̈ misses the servo-constraints by |σ_q q̈ + ρ_s| <= {servo:.2g}, the "
                f"geometric ones by |φ_q q̈ + ρ| <= {geo:.2g}): {err} at {where}")
    return f"{err} at {where}"


def _segments(group: list[dict], indices) -> list[list[dict]]:
    """Runs in the order of `indices`, split where the failure kind changes."""
    segments: list[list[dict]] = []
    for i in indices:
        r = group[i]
        if segments and _category(segments[-1][0]) == _category(r):
            segments[-1].append(r)
        else:
            segments.append([r])
    return segments


def _band(group: list[dict], limit: float) -> tuple[int, int] | None:
    """Indices (lo, hi) of the widest contiguous run of good rows (finished, error <= limit)."""
    good = [_ok(r) and _err(r) <= limit for r in group]
    best = None
    i = 0
    while i < len(group):
        j = i
        while j < len(group) and good[j]:
            j += 1
        if j > i and (best is None or j - i > best[1] - best[0] + 1):
            best = (i, j - 1)
        i = max(j, i + 1)
    return best


def findings(rows: list[dict], alpha_mode: str = "tied", tolerance: float = 2.0) -> list[str]:
    """Per method (Ω values with the same outcome merged): the contiguous α range within `tolerance` x
    MLM's max position error, and how the runs below and above it break down."""
    ref = _mlm(rows)
    if ref is None or not _ok(ref):
        return ["no MLM reference: " + (ref["status"] if ref else "not in the grid")]
    ref_err = ref["max_position_error_mm"]
    limit = tolerance * ref_err
    xk = _x_key(alpha_mode)
    symbol = {"tied": "α", "geometric": "α̃", "servo": "α̂", "grid": "α̃"}[alpha_mode]
    lines = [f"reference: MLM max position error {ref_err:.3g} mm; 'good' = finished and max error <= "
             f"{tolerance:g}x MLM = {limit:.3g} mm"]
    groups: dict[tuple, dict[float, list[dict]]] = {}
    for r in rows:
        if r["method"] != "mlm":
            g = (r["iterations"], r["alpha_servo"] if alpha_mode == "grid" else None)
            groups.setdefault(g, {}).setdefault(r["omega"], []).append(r)
    for (n, aserv), by_omega in sorted(groups.items()):
        # Outcome of each Ω: the band and the (kind, α values) of the segments below and above it.
        outcomes: dict[tuple, list[tuple[list[dict], tuple | None]]] = {}
        for omega in sorted(by_omega):
            group = sorted(by_omega[omega], key=lambda r: r[xk])
            band = _band(group, limit)
            if band is None:
                shape: tuple = ("none",)
            else:
                lo, hi = band
                below = _segments(group, range(lo - 1, -1, -1))
                above = _segments(group, range(hi + 1, len(group)))
                shape = (group[lo][xk], group[hi][xk],
                         tuple((_category(s[0]), tuple(r[xk] for r in s)) for s in below),
                         tuple((_category(s[0]), tuple(r[xk] for r in s)) for s in above))
            outcomes.setdefault(shape, []).append((group, band))
        label = method_name(n) + (f", α̂ = {aserv:.0e}" if alpha_mode == "grid" else "")
        for shape, members in outcomes.items():
            omegas = ", ".join(f"{g[0]['omega']:g}" for g, _ in members)
            head = f"{label} (Ω = {omegas}): "
            if shape == ("none",):
                finished = [r for g, _ in members for r in g if _ok(r)]
                if finished:
                    best = min(finished, key=_err)
                    lines.append(head + f"never within {tolerance:g}x MLM; best {best['max_position_error_mm']:.3g} "
                                        f"mm at {symbol} = {best[xk]:.0e}")
                else:
                    lines.append(head + "no run finished: " + "; then ".join(
                        _describe([r for g, _ in members for r in seg], ref_err, xk, symbol)
                        for seg in _segments(members[0][0], range(len(members[0][0])))))
                continue
            group0, (lo0, hi0) = members[0]
            errs = [_err(r) for g, (lo, hi) in members for r in g[lo : hi + 1]]
            decades = math.log10(group0[hi0][xk] / group0[lo0][xk])
            text = (f"good for {group0[lo0][xk]:.0e} <= {symbol} <= {group0[hi0][xk]:.0e} ({decades:g} decades, "
                    f"error {_fmt_range(errs, '.3g', ' mm')})")
            if lo0 == 0 and hi0 == len(group0) - 1:
                text += ", i.e. the whole grid"
            for side, indices in (("below", lambda g, lo, hi: range(lo - 1, -1, -1)),
                                  ("above", lambda g, lo, hi: range(hi + 1, len(g)))):
                per_member = [_segments(g, indices(g, lo, hi)) for g, (lo, hi) in members]
                if not per_member[0]:
                    continue
                merged = [[r for segs in per_member for r in segs[k]] for k in range(len(per_member[0]))]
                text += f"\n    {side}: " + "; then ".join(_describe(seg, ref_err, xk, symbol) for seg in merged)
            lines.append(head + text)
    # How much Ω matters: spread of the max error over Ω at the same method and penalty numbers.
    spread: dict[tuple, list[float]] = {}
    for r in rows:
        if r["method"] != "mlm" and _ok(r):
            spread.setdefault((r["iterations"], r["alpha_geometric"], r["alpha_servo"]), []).append(_err(r))
    conds: dict[tuple, float] = {}
    for r in rows:
        if r["method"] != "mlm" and r.get("cond_penalty_matrix") is not None:
            key = (r["iterations"], r["alpha_geometric"], r["alpha_servo"])
            conds[key] = max(conds.get(key, 0.0), r["cond_penalty_matrix"])
    spreads = [(max(v) / min(v) - 1, max(v) <= limit and conds.get(k, 0.0) <= ILL_CONDITIONED)
               for k, v in spread.items() if len(v) > 1 and min(v) > 0]
    if spreads:
        in_band = [s for s, good in spreads if good]
        text = (f"at most {100 * max(in_band):.2g} % where good and cond(A) <= {ILL_CONDITIONED:.0e}, "
                if in_band else "")
        lines.append(f"Ω: at equal method and penalty numbers the max error differs between the Ω values by "
                     f"{text}at most {100 * max(s for s, _ in spreads):.2g} % over all finished runs")
    failed = [r for r in rows if not _ok(r)]
    if failed:
        kinds = {}
        for r in failed:
            kinds[_category(r)] = kinds.get(_category(r), 0) + 1
        names = {"diverged": "diverged", "not-pd": "A not positive definite", "error": "other errors"}
        lines.append(f"{len(failed)} of {len(rows)} runs did not finish: "
                     + ", ".join(f"{count} {names[k]}" for k, count in kinds.items()))
    return lines


def write_figures(out: Path, rows: list[dict], alpha_mode: str = "tied", tolerance: float = 2.0) -> list[Path]:
    """Tracking error, constraint violation and cond(A) against α: a panel per method, a line per Ω
    (per (Ω, α̂) in grid mode), MLM as a horizontal line; runs that did not finish as red crosses."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    methods = _methods(rows)
    if not methods:
        return []
    xk = _x_key(alpha_mode)
    ref = _mlm(rows)
    omegas = sorted({r["omega"] for r in rows if r["method"] != "mlm"})
    servos = sorted({r["alpha_servo"] for r in rows if r["method"] != "mlm"}) if alpha_mode == "grid" else [None]
    cmap = plt.get_cmap("viridis")
    styles = ["-", "--", ":", "-."]

    def series(method: str):
        for si, aserv in enumerate(servos):
            for oi, omega in enumerate(omegas):
                sel = [r for r in rows if r["method"] == method and r["omega"] == omega
                       and (aserv is None or r["alpha_servo"] == aserv)]
                sel.sort(key=lambda r: r[xk])
                if not sel:
                    continue
                if alpha_mode == "grid":
                    color = cmap(si / max(len(servos) - 1, 1))
                    label, style = f"α̂ = {aserv:.0e}, Ω = {omega:g}", styles[oi % len(styles)]
                else:  # later Ω dashed and thinner: equal curves stay visible on top of each other
                    color, label = cmap(0.85 * oi / max(len(omegas) - 1, 1)), f"Ω = {omega:g} 1/s"
                    style = styles[oi % len(styles)]
                yield sel, color, label, style

    def value(r, key, any_status=False):
        v = r.get(key)
        good = any_status or _ok(r)
        return v if good and v is not None and np.isfinite(v) and v > 0 else np.nan

    figures = [
        ("sweep_tracking_error.png", f"Max position error against the penalty numbers (MLM: no penalty numbers; "
                                     f"dotted: {tolerance:g}x MLM)",
         [("max_position_error_mm", "max |r_SU − r_d| (mm)")]),
        ("sweep_constraints.png", "Constraint violation: the commanded q̈ (what α controls) and the plant (truth)",
         [("max_constraint_accel_residual", "controller max |φ_q q̈ + ρ|"),
          ("max_servo_accel_residual", "controller max |σ_q q̈ + ρ_s|"),
          ("max_constraint_violation", "plant max |φ|")]),
        ("sweep_condition.png", "Condition number of A = M + α̃ φ_qᵀφ_q + α̂ σ_qᵀσ_q (max over states along the run; "
                                "open: at the start, run did not finish)",
         [("cond_penalty_matrix", "cond(A)")]),
    ]
    written = []
    ncol = len(methods)
    for name, title, quantities in figures:
        nrow = len(quantities)
        fig, axes = plt.subplots(nrow, ncol, figsize=(3.3 * ncol + 0.9, 2.6 * nrow + 1.0), sharex=True,
                                 sharey="row", squeeze=False, layout="constrained")
        for qi, (key, ylabel) in enumerate(quantities):
            cond = key == "cond_penalty_matrix"
            for mi, method in enumerate(methods):
                ax = axes[qi, mi]
                failed_x = []
                for si, (sel, color, label, style) in enumerate(series(method)):
                    xs = np.array([r[xk] for r in sel])
                    ys = np.array([value(r, key) for r in sel])
                    lw = max(1.8 - 0.5 * si, 0.8)
                    ax.loglog(xs, ys, style, color=color, marker="o", ms=4 - si * 0.8, lw=lw, label=label)
                    if cond:  # cond(A) at the start state for the runs that did not finish
                        bad = [r for r in sel if not _ok(r)]
                        ax.loglog([r[xk] for r in bad], [value(r, key, True) for r in bad], "o", mfc="none",
                                  color=color, ms=5)
                    failed_x += [r[xk] for r in sel if not _ok(r)]
                if cond:
                    ax.axhline(1 / np.finfo(float).eps, color="gray", lw=1, ls="--", label="1/eps")
                elif ref is not None and _ok(ref):
                    v = value(ref, key)
                    if np.isfinite(v):
                        ax.axhline(v, color="crimson", lw=1.2, label="MLM")
                        if key == "max_position_error_mm":
                            ax.axhline(tolerance * v, color="crimson", lw=0.8, ls=":",
                                       label=f"{tolerance:g}x MLM")
                if failed_x:
                    ax.plot(failed_x, [0.03] * len(failed_x), "x", color="red", ms=7, mew=2,
                            transform=ax.get_xaxis_transform(), label="diverged / error", clip_on=False)
                ax.grid(True, which="major", alpha=0.3)
                if key == "max_constraint_violation" and mi == ncol - 1:
                    # the plant holds |φ| at round-off: show it against a few decades, not its jitter
                    lo, hi = ax.get_ylim()
                    ax.set_ylim(min(lo, hi / 1e3), max(hi, lo * 1e3))
                if qi == 0:
                    ax.set_title(method)
                if qi == nrow - 1:
                    ax.set_xlabel(_x_label(alpha_mode))
                if mi == 0:
                    ax.set_ylabel(ylabel, fontsize=9)
        seen: dict[str, object] = {}  # one legend entry per label over all panels
        for ax in axes.flat:
            handles, labels = ax.get_legend_handles_labels()
            for handle, label in zip(handles, labels, strict=True):
                seen.setdefault(label, handle)
        fig.suptitle(title, fontsize=10)
        fig.legend(list(seen.values()), list(seen.keys()), loc="outside lower center", ncol=min(len(seen), 7),
                   fontsize=8, frameon=False)
        fig.savefig(out / name, dpi=110)
        plt.close(fig)
        written.append(out / name)
    return written


# ---------------------------------------------------------------------------------------------------
# CLI


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="python -m acroboter.sweep",
        description="Penalty-number study: how the penalty and iterative penalty methods track against MLM as "
                    "the penalty numbers α and Ω vary, one closed-loop simulation per grid point on Dask.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--spec", type=Path, default=DEFAULT_SPEC, help="model spec (TOML)")
    p.add_argument("--alphas", default=DEFAULT_ALPHAS,
                   help="penalty numbers: comma-separated values or log ranges START:STOP[:PER_DECADE]")
    p.add_argument("--alpha-mode", choices=ALPHA_MODES, default="tied",
                   help="tied: α̃ = α̂ = α; geometric: sweep α̃ with α̂ from the spec; servo: sweep α̂ with α̃ from "
                        "the spec; grid: every (α̃, α̂) pair")
    p.add_argument("--omegas", default=DEFAULT_OMEGAS, help="Ω values of the constraint penalty, 1/s")
    p.add_argument("--iterations", default=DEFAULT_ITERATIONS,
                   help="iteration counts N of the iterative penalty method (1 = the plain penalty method)")
    p.add_argument("--duration", type=positive(1e6), default=None, help="simulated seconds (default: the whole path)")
    p.add_argument("--tolerance", type=number(1.0, low_open=True), default=2.0,
                   help="a run is 'good' when its max position error is within this factor of MLM's")
    p.add_argument("--out", type=Path, default=Path("results/sweep"), help="output folder")
    p.add_argument("--scheduler", metavar="ADDRESS", default=None,
                   help="use the running Dask scheduler at ADDRESS (e.g. tcp://10.0.0.5:8786) instead of a local "
                        "cluster; its workers need this checkout with the model library built")
    p.add_argument("--workers", type=whole(1, 64), default=2, help="worker processes of the local cluster")
    p.add_argument("--connect-timeout", type=positive(3600.0), default=10.0, help="seconds to wait for --scheduler")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    args = p.parse_args(argv)
    check_out_folder(p, args.out)
    try:
        args.alphas = parse_values(args.alphas, "--alphas")
        args.omegas = parse_values(args.omegas, "--omegas")
        args.iterations = parse_iterations(args.iterations)
    except ValueError as err:
        p.error(str(err))
    return args


@guarded
def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    n_runs = len(make_grid(args.alphas, args.omegas, args.iterations, args.alpha_mode))
    if n_runs > MAX_RUNS:
        print(f"error: the grid has {n_runs} runs, more than {MAX_RUNS}: give fewer --alphas, --omegas or "
              "--iterations (or another --alpha-mode)", file=sys.stderr)
        return 2
    where = args.scheduler or f"a local cluster of {args.workers} worker process(es) on 127.0.0.1"
    print(f"sweep: {n_runs} runs on {where}", file=sys.stderr)
    try:
        result = sweep(args.spec, alphas=args.alphas, omegas=args.omegas, iterations=args.iterations,
                       alpha_mode=args.alpha_mode, duration=args.duration, workers=args.workers,
                       scheduler=args.scheduler, connect_timeout=args.connect_timeout, out=args.out,
                       plots=not args.no_plots, progress=not args.quiet, tolerance=args.tolerance)
    except SweepError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    rows = result.rows
    if not any(_ok(r) for r in rows):
        print(f"error: no run of the sweep succeeded ({rows[0]['status'] if rows else 'no runs'}); see "
              f"{args.out}/sweep.csv", file=sys.stderr)
        return 3
    duration = rows[0]["duration_s"] if rows and rows[0]["duration_s"] is not None else args.duration
    print(f"{len(rows)} runs of {duration:g} s simulated in {result.wall_s:.1f} s wall on {result.workers} "
          f"worker(s)")
    print(format_table(rows, args.alpha_mode))
    print()
    for line in findings(rows, args.alpha_mode, args.tolerance):
        print(line)
    print(f"results in {args.out}/ ({', '.join(p.name for p in result.files)})")
    return 0


if __name__ == "__main__":
    # Run the importable module's main, not this __main__ copy: tasks must pickle as references to
    # acroboter.sweep.run_case (workers import it), never by value.
    from acroboter.sweep import main as _main

    sys.exit(_main())

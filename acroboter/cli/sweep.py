"""Penalty-number study on Dask: `python -m acroboter.sweep` (see --help), or `sweep()` from Python.

The grid (acroboter.studies.penalty_grid): the penalty numbers α (by default α̃ = α̂ = α, one value per decade
from 1e1 to 1e16: the usual range 1e3..1e12 and enough beyond it on both sides to see each method
break down), the constraint penalty's natural frequency Ω, and the methods penalty and iterative-N,
plus one MLM reference run (MLM has no penalty numbers). Every grid point is one closed-loop
simulation of the spec's path, run as one task on a dask.distributed cluster (acroboter.studies.grid): by
default a LocalCluster of worker processes on 127.0.0.1, with --scheduler ADDRESS a running cluster
(its workers need this package and the same checkout, with the model library already built: tasks
never compile). dask is an optional extra: `pip install 'acroboter[dask]'`.

Writes <out>/sweep.csv (one row per run: acroboter.studies.penalty_grid.COLUMNS) and the figures
sweep_tracking_error.png, sweep_constraints.png and sweep_condition.png (acroboter.report.study_figures);
prints a table of the tracking error and the α range over which each method stays within a factor
(--tolerance, 2) of MLM's error, and how it breaks down outside it (acroboter.studies.run_verdicts).
"""

from __future__ import annotations

import argparse
import sys
import time
from contextlib import nullcontext
from dataclasses import dataclass, field
from pathlib import Path

from ..model.controller_parameters import parameter
from ..model.ranges import (
    ALPHA,
    CONNECT_TIMEOUT,
    DURATION,
    ITERATIONS,
    OMEGA,
    TOLERANCE,
    WORKERS,
    Range,
)
from ..model.settings import resolve_gains
from ..process.interrupts import exit_status
from ..process.locations import example_spec
from ..report.study_figures import sweep_figures
from ..studies.grid import (
    MAX_RUNS,
    GridError,
    open_client,
    parse_values,
    prepare,
    require_dask,
    worker_count,
    write_rows,
)
from ..studies.penalty_grid import (
    ALPHA_MODES,
    COLUMNS,
    make_grid,
    parse_iterations,
    run_sweep,
)
from ..studies.run_verdicts import findings, format_table, ok
from .entry import (
    EXIT_BAD_INPUT,
    EXIT_CANNOT_RUN,
    as_option_text,
    carrying,
    guarded,
    progress_disabled,
    ranged,
    ranged_list,
    spec_file,
)
from .outputs import FAILED, out_path, results_folder

DEFAULT_SPEC = example_spec("acroboter")
DEFAULT_ALPHAS = "1e1:1e16"
DEFAULT_OMEGAS = "5,10,20"
DEFAULT_ITERATIONS = "1,3,5,10"
WHAT = "acroboter sweep"  # names the command in the missing-dask message


@dataclass
class SweepResult:
    rows: list[dict]
    wall_s: float
    workers: int
    files: list[Path] = field(default_factory=list)
    failed: bool = False  # no run succeeded: the files are in <out>/failed/sweep/


def sweep(spec_path: Path = DEFAULT_SPEC, *, alphas: list[float] | None = None, omegas: list[float] | None = None,
          iterations: list[int] | None = None, alpha_mode: str = "tied", duration: float | None = None,
          workers: int = 2, scheduler: str | None = None, connect_timeout: float = 10.0, out: Path | None = None,
          plots: bool = True, progress: bool = False, tolerance: float = 2.0, kp: float | None = None,
          kd: float | None = None, mu: float | None = None) -> SweepResult:
    """The whole study as a function: build the model once here, run the grid on the cluster, and
    (with `out`) write sweep.csv and the figures. Raises GridError when it cannot run at all
    (MissingExtraError, an ImportError, without dask)."""
    require_dask(WHAT)  # first: a missing extra costs no build
    alphas = alphas or parse_values(DEFAULT_ALPHAS)
    omegas = omegas or parse_values(DEFAULT_OMEGAS)
    iterations = iterations or parse_iterations(DEFAULT_ITERATIONS)
    for name, values, range_ in (("alphas", alphas, ALPHA), ("omegas", omegas, OMEGA), ("iterations", iterations,
                                                                                          ITERATIONS)):
        for value in values:  # a RangeError (ValueError) before any work: "alphas: expected 1 <= alpha <= 1e16, …"
            range_.check(value, name)
    for name, value in (("kp", kp), ("kd", kd), ("mu", mu)):
        if value is not None:
            parameter(name).range.check(value, name)
    # `out` checked before any work (OutputFolderError); the files are staged and swapped in at the end
    with results_folder(out, "sweep", expected=["sweep.csv"]) if out is not None else nullcontext() as folder:
        spec = prepare(spec_path, duration)  # builds the library here if missing: the tasks only load it
        try:  # kp, kd sampled at the spec's rate, before any task
            resolve_gains(spec, kp=kp, kd=kd, mu=mu)
        except ValueError as err:
            raise GridError(as_option_text(err)) from None
        pen = spec.controller.penalty
        cases = make_grid(alphas, omegas, iterations, alpha_mode, pen.alpha_geometric, pen.alpha_servo)
        t0 = time.perf_counter()
        with open_client(scheduler, workers, connect_timeout) as client:
            n_workers = worker_count(client) if scheduler else workers
            rows = run_sweep(client, Path(spec_path), cases, duration, progress=progress, kp=kp, kd=kd, mu=mu)
        result = SweepResult(rows, time.perf_counter() - t0, n_workers)
        if folder is not None:
            staged = [folder.staging / "sweep.csv"]
            write_rows(staged[0], rows, COLUMNS)
            if plots:
                staged += sweep_figures(folder.staging, rows, alpha_mode, tolerance)
            result.files = [folder.out / p.relative_to(folder.staging) for p in staged]
            if any(ok(r) for r in rows):
                folder.publish()
            else:  # a failed sweep (exit 3) keeps the last good one's files: its records go to failed/sweep/
                result.failed = True
                folder.publish_failed(f"no run of the sweep succeeded ({rows[0]['status'] if rows else 'no runs'})")
                result.files = [folder.out / FAILED / "sweep" / p.relative_to(folder.staging) for p in staged]
    return result


# ---------------------------------------------------------------------------------------------------
# CLI


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="acroboter sweep",
        description="Penalty-number study: how the penalty and iterative penalty methods track against MLM as "
                    "the penalty numbers α and Ω vary, one closed-loop simulation per grid point on Dask.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--spec", type=spec_file, default=DEFAULT_SPEC,
                   help="model spec: a TOML file or an example's name (acroboter examples)")
    p.add_argument("--alphas", type=_grid_axis(ALPHA), default=DEFAULT_ALPHAS,
                   help="penalty numbers, each 1..1e16: comma-separated values or log ranges START:STOP[:PER_DECADE]")
    p.add_argument("--alpha-mode", choices=ALPHA_MODES, default="tied",
                   help="tied: α̃ = α̂ = α; geometric: sweep α̃ with α̂ from the spec; servo: sweep α̂ with α̃ from "
                        "the spec; grid: every (α̃, α̂) pair")
    p.add_argument("--omegas", type=_grid_axis(OMEGA), default=DEFAULT_OMEGAS,
                   help="Ω values of the constraint penalty, 1/s, each at most 1e4 (values or log ranges)")
    p.add_argument("--iterations", type=ranged_list(ITERATIONS), default=DEFAULT_ITERATIONS,
                   help="iteration counts N of the iterative penalty method, 1..1000 (1 = the plain penalty method)")
    p.add_argument("--duration", type=ranged(DURATION), default=None,
                   help="simulated seconds (default: the whole path)")
    p.add_argument("--tolerance", type=ranged(TOLERANCE), default=2.0,
                   help="a run is 'good' when its max position error is within this factor of MLM's")
    p.add_argument("--out", type=out_path, default=Path("results/sweep"), help="output folder")
    p.add_argument("--scheduler", metavar="ADDRESS", default=None,
                   help="use the running Dask scheduler at ADDRESS (e.g. tcp://10.0.0.5:8786) instead of a local "
                        "cluster; its workers need this checkout with the model library built")
    p.add_argument("--workers", type=ranged(WORKERS), default=2, help="worker processes of the local cluster")
    p.add_argument("--connect-timeout", type=ranged(CONNECT_TIMEOUT), default=10.0,
                   help="seconds to wait for --scheduler")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar (the same as `acroboter -q sweep`)")
    args = p.parse_args(argv)
    require_dask(WHAT)  # the options checked, before --out is made: without dask the one line is the error (exit 2)
    return args


def _grid_axis(range_: Range):
    """The type of a grid axis (--alphas, --omegas): values and log ranges (acroboter.studies.grid.parse_values),
    each value in `range_`."""

    def parse(text: str) -> list[float]:
        try:
            return parse_values(text, "", range_)
        except ValueError as err:
            raise argparse.ArgumentTypeError(str(err)) from None

    return carrying(parse, range_.name, (range_,), "{}")


@guarded
def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    n_runs = len(make_grid(args.alphas, args.omegas, args.iterations, args.alpha_mode))
    if n_runs > MAX_RUNS:
        print(f"error: the grid has {n_runs} runs, more than {MAX_RUNS}: give fewer --alphas, --omegas or "
              "--iterations (or another --alpha-mode)", file=sys.stderr)
        return EXIT_BAD_INPUT
    where = args.scheduler or f"a local cluster of {args.workers} worker process(es) on 127.0.0.1"
    try:
        print(f"sweep: {n_runs} runs on {where}", file=sys.stderr)
        result = sweep(args.spec, alphas=args.alphas, omegas=args.omegas, iterations=args.iterations,
                       alpha_mode=args.alpha_mode, duration=args.duration, workers=args.workers,
                       scheduler=args.scheduler, connect_timeout=args.connect_timeout, out=args.out,
                       plots=not args.no_plots, progress=not progress_disabled(args.quiet), tolerance=args.tolerance)
    except GridError as err:
        print(f"error: {err}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt as err:  # also SIGTERM, SIGHUP (acroboter.process.interrupts)
        print("interrupted", file=sys.stderr)
        return exit_status(err)
    rows = result.rows
    if not any(ok(r) for r in rows):
        print(f"error: no run of the sweep succeeded ({rows[0]['status'] if rows else 'no runs'}); see "
              f"{args.out / FAILED / 'sweep'}/sweep.csv (the results in {args.out}/ are those of its last good run, "
              "as they were)", file=sys.stderr)
        return EXIT_CANNOT_RUN
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
    # The tasks (acroboter.studies.penalty_grid.run_case) live in an importable module: they pickle as
    # references however this one is started.
    sys.exit(main())

"""Monte Carlo robustness study: `acroboter robustness` (see --help), or `robustness()` from Python.

N plants are drawn around the spec's physical parameters (acroboter.studies.robustness_grid: masses ±10 %,
inertias ±20 %, point positions ±5 mm, cable lengths ±2 mm by default, uniform, sample i seeded by
(seed, i)); on each, every method (MLM, penalty, iterative-3/4/5) runs the spec's path with the
PD law (ki = 0) and with integral action (ki: docs/integral_action.md's choice for the spec's kp, kd,
18.375 for kp = kd = 5), while the controllers keep the spec's model. One task per sample, on a
dask.distributed cluster (acroboter.studies.grid: a LocalCluster on 127.0.0.1 by default, --scheduler a
running one, --workers 0 in this process); tasks never compile.

Writes <out>/robustness.csv (one row per sample, method and ki: the sample's parameters, max and RMS
position error, max yaw error, time saturated, diverged, success at the paper's 5.3 mm / 1.1°),
samples.csv (per sample its parameters and the `acroboter run` lines that re-run it), summary.json
(provenance and the tables) and the figures robustness_cdf.png, robustness_success.png and
robustness_worst.png (the worst sample, re-run here).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import platform
import sys
from contextlib import nullcontext
from datetime import UTC, datetime
from pathlib import Path

from ..model.ranges import (
    CONNECT_TIMEOUT,
    DELAY,
    DURATION,
    INTEGRAL_GAIN,
    NOISE,
    SAMPLES,
    SEED,
    WORKERS_OR_NONE,
)
from ..process.locations import example_spec
from ..studies.grid import (
    MAX_RUNS,
    GridError,
    require_dask,
    write_rows,
)
from ..studies.robustness_grid import (
    DEFAULT_METHODS,
    GROUPS,
    POSITION_BOUND_MM,
    SETTLE_S,
    YAW_BOUND_DEG,
    columns,
    command,
    default_ranges,
    group_range,
    parse_range,
)
from ..studies.robustness_study import RobustnessResult, rerun_worst, run_study
from .entry import (
    EXIT_BAD_INPUT,
    carrying,
    guarded,
    named_number,
    progress_disabled,
    ranged,
    spec_file,
)
from .outputs import out_path, results_folder

DEFAULT_SPEC = example_spec("acroboter")
DEFAULT_SAMPLES, DEFAULT_SEED, DEFAULT_DURATION = 200, 12, 20.0
MAX_SAMPLES = SAMPLES.high
WHAT = "acroboter robustness"
NO_DASK = "--workers 0 runs in this process without it"


def parse_sensing(noise: list[tuple[str, float]], delay: int | None, seed: int | None) -> dict:
    """The --sensing-* options (each number in its range already) as `Crane.simulate(sensing=...)` overrides
    (checked again there, by the spec)."""
    sensing: dict = {}
    for group, value in noise:
        sensing.setdefault("noise", {})[group] = value
    if delay is not None:
        sensing["delay_periods"] = delay
    if seed is not None:
        sensing["seed"] = seed
    return sensing

def robustness(spec_path: Path = DEFAULT_SPEC, *, samples: int = DEFAULT_SAMPLES, seed: int = DEFAULT_SEED,
               duration: float = DEFAULT_DURATION, ranges: dict | None = None,
               methods: tuple[str, ...] = DEFAULT_METHODS, ki: float | None = None, workers: int = 2,
               scheduler: str | None = None, connect_timeout: float = 10.0, out: Path | None = None,
               plots: bool = True, progress: bool = False, sensing=None, command_line: list[str] | None = None,
               fast: bool = False) -> RobustnessResult:
    """The whole study: draw the samples, run them (workers = 0: in this process; acroboter.studies.robustness_study),
    and (with `out`) write the CSVs, summary.json and the figures. Raises GridError when it cannot run at all;
    ValueError for bad numbers (samples < 1, a bad range)."""
    if isinstance(samples, bool) or not isinstance(samples, int) or not 1 <= samples <= MAX_SAMPLES:
        raise ValueError(f"samples: expected a whole number from 1 to {MAX_SAMPLES}, found {samples!r}")
    ranges = {**default_ranges(), **{g: parse_range(":".join(map(repr, r)) if isinstance(r, tuple) else r, g)
                                     for g, r in (ranges or {}).items()}}
    if samples * len(methods) * 2 > MAX_RUNS:
        raise ValueError(f"{samples} samples × {len(methods)} methods × 2 is more than {MAX_RUNS} runs")
    if scheduler or workers > 0:
        require_dask(WHAT, NO_DASK)  # first: a missing extra costs no build
    # `out` checked before any work (OutputFolderError); the files are staged and swapped in at the end
    expected = ["robustness.csv", "samples.csv", "summary.json"]
    with results_folder(out, "robustness", expected=expected) if out is not None else nullcontext() as folder:
        result = run_study(spec_path, samples=samples, seed=seed, duration=duration, ranges=ranges,
                           methods=methods, ki=ki, workers=workers, scheduler=scheduler,
                           connect_timeout=connect_timeout, progress=progress, sensing=sensing, fast=fast)
        from ..report.robustness_report import summarize

        result.summary = summarize(result.rows, methods, (0.0, result.ki))
        if folder is not None:
            _write(folder.staging, result, result.spec, spec_path, seed, duration, ranges, methods, plots,
                   command_line, sensing, fast)
            folder.publish()
            result.files = [folder.out / p.relative_to(folder.staging) for p in result.files]
    return result


def _write(out: Path, result: RobustnessResult, spec, spec_path, seed, duration, ranges, methods, plots,
           command_line, sensing, fast) -> None:
    cols = columns(result.samples[0])
    write_rows(out / "robustness.csv", result.rows, cols)
    sample_rows = [{"sample": s.index, "draws": s.draws, "mass_error": s.mass_error,
                    "tracked_mass_error": s.tracked_mass_error, **s.params,
                    "command": command(spec_path, s, duration, sensing=sensing, fast=fast),
                    "command_ki": command(spec_path, s, duration, ki=result.ki, sensing=sensing, fast=fast)}
                   for s in result.samples]
    write_rows(out / "samples.csv", sample_rows,
               ["sample", "draws", "mass_error", "tracked_mass_error", *result.samples[0].params, "command",
                "command_ki"])
    result.files += [out / "robustness.csv", out / "samples.csv"]
    worst = None
    if plots:
        from ..report.study_figures import robustness_figures

        worst = rerun_worst(spec_path, result, duration, methods, sensing, fast) if result.rows else None
        result.files += robustness_figures(out, result.rows, worst=worst)
    summary = {
        "provenance": {
            "command_line": command_line, "started_utc": datetime.now(UTC).isoformat(timespec="seconds"),
            "spec": str(spec_path), "spec_name": spec.name,
            "spec_sha256": hashlib.sha256(Path(spec_path).read_bytes()).hexdigest(),
            "seed": seed, "samples": len(result.samples), "duration_s": duration,
            "sampling": "uniform; sample i from numpy.random.default_rng((seed, i)), one draw per parameter in "
                        "acroboter.model.physical.parameter_names order, redrawn while the spec refuses it",
            "ranges": {g: {"low": lo, "high": hi, "unit": GROUPS[g][1], "what": GROUPS[g][0]}
                       for g, (lo, hi) in ranges.items()},
            "methods": list(methods), "ki": [0.0, result.ki], "kp": spec.controller.kp, "kd": spec.controller.kd,
            "sensing": sensing, "fast_path": fast,
            "bounds": {"position_mm": POSITION_BOUND_MM, "yaw_deg": YAW_BOUND_DEG}, "settled_after_s": SETTLE_S,
            "versions": _versions(), "workers": result.workers, "wall_s": result.wall_s,
        },
        **result.summary,
        "worst_sample": None if worst is None else {k: worst[k] for k in ("sample", "mass_error", "tracked_mass_error",
                                                                       "command")},
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2, default=float) + "\n", encoding="utf-8")
    result.files.append(out / "summary.json")


def _versions() -> dict:
    from importlib.metadata import PackageNotFoundError, version

    found = {"python": platform.python_version()}
    for name in ("acroboter", "numpy", "casadi", "dask", "distributed"):
        try:
            found[name] = version(name)
        except PackageNotFoundError:
            found[name] = None
    return found


# ---------------------------------------------------------------------------------------------------
# CLI


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="acroboter robustness",
        description="Monte Carlo robustness study: every method, with and without integral action, on plants "
                    "whose physical parameters are drawn around the model's (the controllers keep the model).",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--spec", type=spec_file, default=DEFAULT_SPEC,
                   help="model spec: a TOML file or an example's name (acroboter examples)")
    p.add_argument("--samples", type=ranged(SAMPLES), default=DEFAULT_SAMPLES, metavar="N",
                   help="number of plant samples")
    p.add_argument("--seed", type=ranged(SEED), default=DEFAULT_SEED, metavar="S",
                   help="seed: sample i is drawn from numpy's default_rng((S, i)), so any one can be drawn alone")
    p.add_argument("--duration", type=ranged(DURATION), default=DEFAULT_DURATION,
                   help="simulated seconds of the path")
    p.add_argument("--ki", type=ranged(INTEGRAL_GAIN), default=None,
                   help="k_I of the integral-action rows, 1/s³ (default: docs/integral_action.md's choice for the "
                        "spec's kp, kd: 18.375 for kp = kd = 5)")
    p.add_argument("--methods", default=",".join(DEFAULT_METHODS), help="comma-separated methods")
    for group, (what, unit, half, _) in GROUPS.items():
        bounds = group_range(group)
        p.add_argument(f"--{group}-range", type=_range_type(group), default=None, metavar="H|LO:HI",
                       help=f"range of the {what}, {unit}: ±H or LO:HI, within {bounds.low:g}..{bounds.high:g} "
                            f"(default ±{half:g})")
    p.add_argument("--sensing-noise", action="append", default=[], metavar="GROUP=STD",
                   type=named_number(NOISE, "positions=0.0002", "GROUP=STD"),
                   help="measurement noise (standard deviation, m or unitless) of a sensing group, e.g. "
                        "positions=0.0002; repeatable (acroboter.sim.sensing, docs/sensing.md); default: none")
    p.add_argument("--sensing-delay", type=ranged(DELAY), default=None, metavar="N",
                   help="measurement delay in whole control periods, shorter than --duration (default: none)")
    p.add_argument("--sensing-seed", type=ranged(SEED), default=None, metavar="N",
                   help="seed of the measurement noise (the same for every sample; default: the spec's, 0)")
    p.add_argument("--out", type=out_path, default=Path("results/robustness"), help="output folder")
    p.add_argument("--scheduler", metavar="ADDRESS", default=None,
                   help="use the running Dask scheduler at ADDRESS instead of a local cluster; its workers need "
                        "this checkout with the model library built")
    p.add_argument("--workers", type=ranged(WORKERS_OR_NONE), default=2,
                   help="worker processes of the local cluster (0: run in this process, no dask needed)")
    p.add_argument("--connect-timeout", type=ranged(CONNECT_TIMEOUT), default=10.0,
                   help="seconds to wait for --scheduler")
    p.add_argument("--fast", action="store_true",
                   help="the controllers' fast path (one compiled function per control step, docs/fast-path.md; the "
                        "same results within 1e-9 relative, its libraries built in the cache first)")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG figures (and the worst sample's re-run)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar (the same as `acroboter -q robustness`)")
    args = p.parse_args(argv)
    args.ranges = {g: getattr(args, f"{g}_range") for g in GROUPS if getattr(args, f"{g}_range") is not None}
    args.sensing = None
    if args.sensing_noise or args.sensing_delay is not None or args.sensing_seed is not None:
        try:
            args.sensing = parse_sensing(args.sensing_noise, args.sensing_delay, args.sensing_seed)
        except ValueError as err:
            p.error(str(err))
    args.methods = tuple(m.strip() for m in args.methods.split(",") if m.strip())
    from ..model.spec import MAX_ITERATIONS

    for m in args.methods:
        count = m.removeprefix("iterative-")
        if m not in ("mlm", "penalty") and not (m.startswith("iterative-") and count.isdigit()
                                                and 1 <= int(count) <= MAX_ITERATIONS):
            p.error(f"--methods: unknown method '{m}': use mlm, penalty or iterative-N (1 <= N <= {MAX_ITERATIONS})")
    if not args.methods:
        p.error("--methods: no method given")
    if args.scheduler or args.workers:  # the options checked, before --out is made: the one line is the error
        require_dask(f"{WHAT} {'--scheduler' if args.scheduler else f'--workers {args.workers}'}", NO_DASK)
    return args


def _range_type(group: str):
    """The type of --<group>-range: ±H or LO:HI, both bounds in the group's range (robustness_grid.group_range)."""

    def parse(text: str) -> tuple[float, float]:
        try:
            return parse_range(text, group, "")
        except ValueError as err:
            raise argparse.ArgumentTypeError(str(err)) from None

    return carrying(parse, f"{group}_range", (group_range(group),), "{}")


@guarded
def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    via_cli = Path(sys.argv[0]).name in ("acroboter", "__main__.py")
    command_line = [*(["acroboter", "robustness"] if via_cli else ["python", "-m", "acroboter.robustness"]),
                    *(sys.argv[1:] if argv is None else argv)]
    where = (args.scheduler or (f"a local cluster of {args.workers} worker process(es) on 127.0.0.1"
                                if args.workers else "this process"))
    try:
        print(f"robustness: {args.samples} samples × {len(args.methods)} methods × 2 (ki) on {where}",
              file=sys.stderr)
        result = robustness(args.spec, samples=args.samples, seed=args.seed, duration=args.duration,
                            ranges=args.ranges, methods=args.methods, ki=args.ki, workers=args.workers,
                            scheduler=args.scheduler, connect_timeout=args.connect_timeout, out=args.out,
                            plots=not args.no_plots, progress=not progress_disabled(args.quiet),
                            sensing=args.sensing, command_line=command_line, fast=args.fast)
    except (GridError, ValueError) as err:
        print(f"error: {err}", file=sys.stderr)
        return EXIT_BAD_INPUT
    from ..report.robustness_report import findings, format_table

    print(f"{len(result.rows)} runs of {args.duration:g} s simulated in {result.wall_s:.1f} s wall on "
          f"{result.workers or 'no'} worker(s) (ki = {result.ki:g})")
    print(format_table(result.summary))
    print()
    for line in findings(result.summary):
        print(line)
    worst = max((r for r in result.rows if r["method"] is not None),
                key=lambda r: math.inf if r["status"] != "ok" else r["max_position_error_mm"])
    err = worst["max_position_error_mm"]
    print(f"worst run: sample {worst['sample']}, {worst['method']}, ki = {worst['ki']:g} ({worst['status']}"
          + ("" if err is None else f", max position error {err:.3f} mm") + "); re-run it with\n  "
          + command(args.spec, result.samples[worst["sample"]], args.duration, worst["method"], worst["ki"],
                    sensing=args.sensing, fast=args.fast))
    print(f"every sample's re-run lines: {args.out}/samples.csv")
    print(f"results in {args.out}/ ({', '.join(p.name for p in result.files)})")
    return 0


if __name__ == "__main__":
    sys.exit(main())

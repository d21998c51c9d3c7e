"""Retime the path under the input limits: `acroboter plan` (or `python -m acroboter.plan`; see --help).

A thin layer over the library (acroboter.Crane.plan, docs/planning.md): the fastest timing of the spec's path
(or of a trajectory file's geometry) whose ideal motion keeps every input within its limits less the margin,
certified by flying it with the spec's controllers (--certify, MLM by default) on the own plant, limits applied.
Writes into --out (staged, swapped in whole):
trajectory.csv (what `acroboter run --trajectory FILE` reads), summary.json (duration, where the limits are
active, the margin achieved, the certificate, provenance) and plan.png (s(t) and the inputs against the limits).

Exit codes: 0 planned; 2 bad input (an option, the spec, a trajectory file, limits that cannot hold the load at
rest somewhere on the path: no timing can help, the place and the input named); 3 no plan (the problem not
solved; a plan that is not the one asked for, a solve that did not reach the optimum (a fallback timing), a
--max-speed/--max-accel/--max-jerk the written samples exceed, a failed certificate or a --tolerance not met, is
written into failed/plan/, its summary's status saying which, beside the last plan that held);
130 interrupted.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..model.ranges import MARGIN, PLAN_ACCEL, PLAN_INTERVALS, PLAN_JERK, PLAN_SPEED, PLAN_TOLERANCE, PLAN_WINDOW
from ..process.interrupts import exit_status
from ..process.locations import example_spec
from .entry import carrying, guarded, ranged, spec_file
from .outputs import out_path, results_folder

FILES = ("trajectory.csv", "summary.json", "plan.png")


def _percent(text: str) -> float:
    """'5%' or '0.05': a fraction in MARGIN's range."""
    try:
        raw = str(text).strip()
        value = float(raw[:-1]) / 100.0 if raw.endswith("%") else float(raw)
        return MARGIN.check(value, "margin")
    except ValueError as err:
        message = str(err) if str(err).startswith("margin") else f"margin: expected a fraction or a percentage " \
                                                                 f"({MARGIN.text()}), found {text!r}"
        raise argparse.ArgumentTypeError(message) from None


# --tolerance's units, in metres
LENGTH_UNITS = {"mm": 1e-3, "um": 1e-6, "µm": 1e-6, "m": 1.0}


def _length(text: str) -> float:
    """'0.1mm', '100um', '1e-4m' or a bare number of millimetres: metres in PLAN_TOLERANCE's range."""
    raw = str(text).strip()
    unit = next((u for u in ("mm", "um", "µm", "m") if raw.endswith(u)), "mm")
    number = raw[: len(raw) - len(unit)].strip() if raw.endswith(unit) else raw
    try:
        value = float(number) * LENGTH_UNITS[unit]
    except ValueError:
        raise argparse.ArgumentTypeError(f"tolerance: expected a length as 0.1mm, 100um or 1e-4m (a bare number is in "
                                         f"mm), found {text!r}") from None
    try:
        return PLAN_TOLERANCE.check(value, "tolerance")
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"{err} (metres; from {text!r})") from None


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="acroboter plan",
        description="Retime the spec's path (or a trajectory file's geometry) to the fastest timing whose ideal "
                    "motion keeps every input within its limits less a margin (docs/planning.md).")
    p.add_argument("--spec", type=spec_file, default=example_spec("acroboter"),
                   help="model spec: a TOML file or an example's name (default: %(default)s)")
    p.add_argument("--margin", type=carrying(_percent, "margin", (MARGIN,), "{}"), default=0.05,
                   help="the fraction of each input's limit span kept free on each side, as 5%% or 0.05, "
                        "0 <= margin < 50%% (default: 5%%)")
    p.add_argument("--max-speed", type=ranged(PLAN_SPEED), default=None, metavar="M_S",
                   help="a bound on the tracked point's speed, m/s, at most 100 (default: none)")
    p.add_argument("--max-accel", type=ranged(PLAN_ACCEL), default=None, metavar="M_S2",
                   help="a bound on the tracked point's acceleration, m/s², at most 1000 (default: none)")
    p.add_argument("--max-jerk", type=ranged(PLAN_JERK), default=None, metavar="M_S3",
                   help="a bound on the tracked point's jerk, m/s³, at most 1e5: the timing is then smooth (σ̈ "
                        "continuous, 0 at every corner) (default: none, σ̈ held per interval)")
    p.add_argument("--tolerance", type=carrying(_length, "tolerance", (PLAN_TOLERANCE,), "{}m"), default=None,
                   metavar="LENGTH",
                   help="the position error every --certify method may fly the plan with, as 0.1mm, 100um or 1e-4m "
                        "(a bare number is in mm), 0.1 µm to 1 m: the fastest smooth timing whose flights stay "
                        "within it, at any phase of the controller's clock, compared with the time-optimal timing "
                        "and its best uniform slowdown that meets it (docs/planning.md) (default: none)")
    p.add_argument("--trajectory", type=Path, default=None, metavar="FILE",
                   help="retime this trajectory file's geometry instead of the spec's waypoints (the CSV format "
                        "of docs/planning.md: t_s, x_m, y_m, z_m, vx_m_s, ...)")
    p.add_argument("--intervals", type=ranged(PLAN_INTERVALS), default=120,
                   help="the optimiser's grid: intervals over the whole path, 4..5000 (default: %(default)s)")
    p.add_argument("--corners", choices=("rest", "swing"), default="rest",
                   help="a waypoint path's corners: rest, every edge from rest to rest with the connector's swing "
                        "(solved edge by edge); swing, the swing carried over the corners (edges optimised together, "
                        "see --window) (default: %(default)s)")
    p.add_argument("--shaper", choices=("zv", "zvd", "unshaped"), default=None,
                   help="no optimiser: each edge's own timing convolved with a zero-vibration shaper (zv, zvd) for "
                        "the crane's swing modes, or not (unshaped), slowed edge by edge to the fastest that keeps the "
                        "limits less the margin and ends at rest, the swing carried over (docs/planning.md) "
                        "(default: none, the time-optimal timing)")
    p.add_argument("--window", type=ranged(PLAN_WINDOW), default=None,
                   help="with --corners swing: phases (edges) optimised together in a receding window, each window "
                        "from the state the phases before it leave; 0 solves the whole path at once (slow on long "
                        "paths), 0..1000 (default: 2)")
    p.add_argument("--certify", default="mlm", metavar="METHODS",
                   help="the methods that fly the plan in its certificate, at the spec's rate on the own plant with "
                        "the limits applied: mlm, penalty, iterative or iterative-N, comma-separated (default: "
                        "%(default)s)")
    p.add_argument("--no-certificate", action="store_true",
                   help="skip flying the plan (the certificate)")
    p.add_argument("--out", type=out_path, default=Path("results/plan"), help="output folder (default: %(default)s)")
    p.add_argument("--cache-dir", type=Path, default=None,
                   help="where compiled models are cached (default: $ACROBOTER_CACHE_DIR, else the per-user cache)")
    p.add_argument("--no-plots", action="store_true", help="skip plan.png")
    p.add_argument("-q", "--quiet", action="store_true", help="print only the result's line")
    args = p.parse_args(argv)
    if args.no_certificate and args.tolerance is not None:
        p.error("--tolerance is judged by flying the plan: it cannot go with --no-certificate")
    if args.shaper is not None:
        clash = [name for name, given in (("--tolerance", args.tolerance is not None), ("--trajectory",
                 args.trajectory is not None), ("--corners swing", args.corners != "rest"),
                 ("--window", args.window is not None)) if given]
        if clash:
            p.error("--shaper shapes the spec's waypoint edges without an optimiser, the swing carried over the "
                    f"corners: it cannot go with {', '.join(clash)}")
    from .run_args import expand_methods

    try:
        args.certify = expand_methods([args.certify], [3])
    except ValueError as err:
        p.error(f"--certify: {err}")
    try:
        if args.out.exists() and not args.out.is_dir():
            p.error(f"--out {args.out} is a file, not a folder")
    except OSError as err:
        p.error(f"cannot use --out {args.out}: {err.strerror or err}")
    return args


@guarded
def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    args.command_line = ["acroboter", "plan", *(sys.argv[1:] if argv is None else argv)]
    existed = args.out.exists()
    try:
        with results_folder(args.out, "plan", expected=["summary.json"]) as folder:
            return _plan(args, folder)
    except KeyboardInterrupt as err:  # also SIGTERM, SIGHUP (acroboter.process.interrupts)
        earlier = f"the earlier ones in {args.out} are as they were" if existed else f"{args.out} was not created"
        print(f"interrupted: no plan written ({earlier})", file=sys.stderr)
        return exit_status(err)


def _plan(args: argparse.Namespace, folder) -> int:
    import json

    from ..api.crane import Crane
    from ..control.path import TrajectoryError
    from ..control.trajectory_file import read_trajectory_csv
    from ..model.spec import SpecError
    from ..planning.checks import StaticLimitError
    from ..planning.ideal_motion import PlanningError
    from ..planning.planner import PlanFailure
    from ..runtime.compiled import StaleModelError
    from ..sim.statics import EquilibriumError
    from .run import provenance

    folder.claim(list(FILES[:2]) + ([] if args.no_plots else [FILES[2]]))
    try:
        crane = Crane.from_toml(args.spec, cache_dir=args.cache_dir)
        trajectory = read_trajectory_csv(args.trajectory) if args.trajectory is not None else None
        crane.desired(trajectory)  # its shapes and times checked before any work
    except (SpecError, StaleModelError, EquilibriumError, TrajectoryError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    failure = None
    try:
        plan = crane.plan(margin=args.margin, max_speed=args.max_speed, max_accel=args.max_accel,
                          trajectory=trajectory, intervals=args.intervals,
                          certify=False if args.no_certificate else args.certify,
                          window=args.window, corners=args.corners, max_jerk=args.max_jerk, tolerance=args.tolerance,
                          shaper=args.shaper)
    except (StaticLimitError, TrajectoryError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except PlanFailure as err:  # a plan, but not the one asked for (a fallback, a bound, the certificate)
        plan, failure = err.plan, str(err)
    except PlanningError as err:
        print(f"error: {err}", file=sys.stderr)
        return 3
    out = folder.staging
    plan.to_csv(out / "trajectory.csv")
    summary = plan.summary()
    summary["spec"] = crane.name
    summary["trajectory_file"] = None if args.trajectory is None else str(args.trajectory)
    args.plant, args.plant_params = "own", {}
    summary["provenance"] = provenance(args, crane.spec, crane.gains(), list(args.certify), plan.duration)
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    if not args.no_plots:
        from ..report.plan_figures import plan_figure

        plan_figure(plan, out / "plan.png")
    if failure is not None:
        written = folder.publish_failed(failure)
        print(f"error: {failure}", file=sys.stderr)
        print(f"not planned ({plan.status}): the timing returned ({plan.duration:.4g} s) is in {written[0].parent}/, "
              f"not a result; the results in {args.out}/ are those of the last plan that held", file=sys.stderr)
        return 3
    folder.publish()
    active = sorted({a["input"] for a in plan.active})
    corners = {"rest": ", every edge rest to rest", "swing": "",
               "shaped": f", input-shaped ({args.shaper}) edge by edge"}[plan.corners]
    print(f"spec {crane.name}: planned {plan.duration:.4g} s{corners} (the path's own timing {plan.path_duration:.4g} "
          f"s, its best uniform slowdown {plan.uniform_duration:.4g} s); margin {100 * plan.margin:.3g} %, achieved "
          f"{100 * plan.margin_achieved:.3g} % planned" + (
              f", {100 * plan.certificate.margin_achieved:.3g} % flown (limits applied, and held "
              f"{plan.certificate.settle_s:g} s past the end; max position error "
              + ", ".join(f"{m} {f['max_position_error_mm']:.3g} mm" for m, f in plan.certificate.flights.items())
              + ")" if plan.certificate is not None else "")
          + f"; limits active: {', '.join(active) or 'none'}; solved in {plan.solve_s:.3g} s")
    for w in plan.warnings:
        print(f"warning: {w}")
    if plan.tolerance is not None:
        print(tolerance_line(plan.tolerance))
    if not args.quiet:
        print(f"results in {args.out}/ (acroboter run --trajectory {args.out}/trajectory.csv flies it)")
    return 0


def tolerance_line(t: dict) -> str:
    """What a plan to a tolerance says on stdout: flown within what, and against the timings it is compared with."""
    solves = sum(r["solve_s"] for r in t["rounds"])
    uniform = t.get("uniform_slowdown_duration_s")
    return (f"tolerance {t['asked_mm']:.3g} mm: flown within {t['flown_mm']:.3g} mm by {', '.join(t['methods'])} at "
            f"every clock phase ({len(t['rounds'])} round(s), {solves:.3g} s of solves); the time-optimal timing "
            f"{t['time_optimal_duration_s']:.4g} s flies at {t['time_optimal_flown_mm']:.3g} mm, its best uniform "
            "slowdown that meets the tolerance " + (f"{uniform:.4g} s" if uniform is not None else "was not found"))


if __name__ == "__main__":
    sys.exit(main())

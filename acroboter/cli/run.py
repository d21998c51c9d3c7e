"""Run the paper's scenario: `acroboter run` (or `python -m acroboter.run`; see --help).

A thin layer over the library (acroboter.Crane.simulate): what it prints and writes is what
`crane.simulate(method, duration=..., **settings).summary()` gives for the same options.

With no arguments: the default spec, MLM, Penalty and Iterative Penalty with the spec's iteration
counts (3, 4, 5), the full path; a table on stdout and results/ with summary.json, one CSV per
method and the figures.
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import sys
import tempfile
from pathlib import Path

from ..model.interrupts import deferred_interrupt
from ..model.locations import example_spec
from ..model.spec import MAX_CONTROL_STEPS, MAX_ITERATIONS
from .entry import guarded, name_value, number, positive, progress_disabled

DEFAULT_SPEC = example_spec("acroboter")


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="acroboter run",
        description="Simulate the crane under the inverse-dynamics controllers and report tracking and timing.",
    )
    p.add_argument("--spec", type=Path, default=DEFAULT_SPEC, help="model spec (TOML) (default: %(default)s)")
    p.add_argument("--method", action="append", metavar="METHOD",
                   help="mlm, penalty, iterative or iterative-N; repeat or comma-separate "
                        "(default: mlm, penalty and iterative with the spec's iteration counts)")
    p.add_argument("--iterations", type=str, default=None,
                   help="iteration counts for 'iterative', comma-separated (default: from the spec)")
    p.add_argument("--recovery", choices=["projected", "eq12", "eq13", "eq15", "kappa"], default=None,
                   help="input recovery of the penalty methods (default: from the spec)")
    p.add_argument("--kappa", type=number(0.0, 1.0), default=None,
                   help="κ of the 'kappa' recovery, 0..1 (default: from the spec)")
    p.add_argument("--alpha-geometric", type=positive(), default=None, help="α̃ (default: from the spec)")
    p.add_argument("--alpha-servo", type=positive(), default=None, help="α̂ (default: from the spec)")
    p.add_argument("--omega", type=positive(), default=None, help="Ω of the constraint penalty, 1/s (default: spec)")
    p.add_argument("--mu", type=positive(), default=None, help="μ of the constraint penalty (default: spec)")
    p.add_argument("--kp", type=positive(), default=None, help="servo gain k_P, 1/s (default: spec)")
    p.add_argument("--kd", type=positive(), default=None, help="servo gain k_D, 1/s (default: spec)")
    p.add_argument("--ki", type=number(0.0), default=None,
                   help="integral gain k_I of the servo error dynamics, 1/s³, below 2·kd·kp²; 0: none "
                        "(default: spec, normally 0; docs/integral_action.md)")
    p.add_argument("--plant-param", action="append", default=[], metavar="NAME=VALUE", dest="plant_param",
                   help="a physical parameter of the plant other than the spec's (the controller keeps the spec's), "
                        "e.g. SU.mass=8.8; repeatable; names: gravity.z, <body>.mass, <body>.inertia.xx, "
                        "<body>.damping.translational, <body>.points.<point>.x, <cable>.length, "
                        "<cable>.winch.reflected_inertia (docs/model.md, 'A plant that differs from the model')")
    p.add_argument("--sensing-noise", action="append", default=[], metavar="GROUP=STD",
                   help="the controller measures instead of reading the plant's state: Gaussian noise (standard "
                        "deviation, m or unitless) of a sensing group, e.g. positions=0.0002; repeatable; groups: the "
                        "spec's [sensing] ones, else positions, axes, lengths (docs/sensing.md)")
    p.add_argument("--sensing-quantization", action="append", default=[], metavar="GROUP=STEP",
                   help="quantisation step of a sensing group (m or unitless), e.g. lengths=0.0001; repeatable")
    p.add_argument("--sensing-delay", default=None, metavar="N",
                   help="measurement delay in whole control periods (default: the spec's, else 0)")
    p.add_argument("--sensing-seed", default=None, metavar="N", help="seed of the measurement noise (default: spec, 0)")
    p.add_argument("--no-sensing", action="store_true",
                   help="ignore the spec's [sensing] section: the controller reads the plant's state")
    p.add_argument("--plant", choices=["own", "mujoco"], default="own",
                   help="the crane the controllers drive: own (the project's Baumgarte RK4 plant) or mujoco (MuJoCo "
                        "on the spec's MJCF model, docs/mujoco.md) (default: %(default)s)")
    p.add_argument("--mujoco-timestep", type=number(0.0, 0.01, low_open=True), default=None, metavar="S",
                   help="MuJoCo's time step with --plant mujoco, dividing the spec's plant step (default: 0.0001)")
    p.add_argument("--view", action="store_true",
                   help="after the run, replay it in MuJoCo's interactive viewer (needs a display)")
    p.add_argument("--duration", type=positive(1e6), default=None, help="simulated seconds (default: the whole path)")
    p.add_argument("--out", type=Path, default=Path("results"), help="output folder (default: %(default)s)")
    p.add_argument("--state", action="store_true",
                   help="add the rates q̇ of the natural coordinates to each CSV (q is always there)")
    p.add_argument("--cache-dir", type=Path, default=None,
                   help="where compiled models are cached (default: $ACROBOTER_CACHE_DIR, else the per-user cache)")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar (the same as `acroboter -q run`)")
    args = p.parse_args(argv)
    if args.mujoco_timestep is not None and args.plant != "mujoco":
        p.error("--mujoco-timestep needs --plant mujoco")
    if args.view:
        from ..report.viewer import display_problem

        args.view_problem = display_problem()
    try:
        if args.out.exists() and not args.out.is_dir():
            p.error(f"--out {args.out} is a file, not a folder")
    except OSError as err:
        p.error(f"cannot use --out {args.out}: {err.strerror or err}")
    args.plant_params = {}
    for item in args.plant_param:
        pair = name_value(item)
        if pair is None or not math.isfinite(pair[1]):
            p.error(f"--plant-param takes NAME=VALUE with a finite number, e.g. SU.mass=8.8, found '{item}'")
        name, value = pair
        if name in args.plant_params:
            p.error(f"--plant-param {name} given twice")
        args.plant_params[name] = value
    args.sensing = _sensing_overrides(p, args)
    if args.iterations is not None:
        try:
            args.iterations = [int(v) for v in args.iterations.split(",")]
        except ValueError:
            p.error(f"--iterations takes comma-separated whole numbers, found '{args.iterations}'")
        if any(not 1 <= i <= MAX_ITERATIONS for i in args.iterations):
            p.error(f"--iterations must be between 1 and {MAX_ITERATIONS}, found {args.iterations}")
    try:
        if args.method is not None and not expand_methods(args.method, args.iterations or [1]):
            p.error(f"--method names no method, found {args.method}")
    except ValueError as err:
        p.error(str(err))
    return args


def _sensing_overrides(p: argparse.ArgumentParser, args: argparse.Namespace):
    """The --sensing-* options as Crane.simulate(sensing=...) takes them (None: the spec's section,
    False: none). Values are checked by the sensing model itself (a SpecError naming the field, exit 2)."""
    given = args.sensing_noise or args.sensing_quantization or args.sensing_delay is not None \
        or args.sensing_seed is not None
    if args.no_sensing:
        if given:
            p.error("--no-sensing goes with no other --sensing-* option")
        return False
    if not given:
        return None
    overrides: dict = {}
    for option, key in ((args.sensing_noise, "noise"), (args.sensing_quantization, "quantization")):
        for item in option:
            pair = name_value(item)
            if pair is None or math.isnan(pair[1]):
                p.error(f"--sensing-{key} takes GROUP=VALUE with a number, e.g. positions=0.0002, found '{item}'")
            overrides.setdefault(key, {})[pair[0]] = pair[1]
    for text, key in ((args.sensing_delay, "delay_periods"), (args.sensing_seed, "seed")):
        if text is not None:
            try:
                overrides[key] = int(text)
            except ValueError:
                try:
                    overrides[key] = float(text)  # refused with the field's name: an integer is expected
                except ValueError:
                    p.error(f"--sensing-{key.split('_')[0]} takes a whole number, found '{text}'")
    return overrides


def expand_methods(requested: list[str] | None, iterations: list[int]) -> list[str]:
    names = []
    for item in requested or ["mlm", "penalty", "iterative"]:
        names += [m.strip() for m in item.split(",") if m.strip()]
    methods = []
    for name in names:
        if name == "iterative":
            methods += [f"iterative-{i}" for i in iterations]
        elif name in ("mlm", "penalty") or (name.startswith("iterative-") and name[10:].isdigit()
                                             and 1 <= int(name[10:]) <= MAX_ITERATIONS):
            methods.append(name)
        else:
            raise ValueError(f"unknown method '{name}': use mlm, penalty, iterative or iterative-N "
                             f"(1 <= N <= {MAX_ITERATIONS})")
    return list(dict.fromkeys(methods))


# The files a run writes into --out: a new run replaces these (and only these) from an earlier one.
FIGURES = ("path_3d.png", "tracking_errors.png", "servo_errors.png", "inputs.png", "control_step_time.png")


def _is_run_file(path: Path) -> bool:
    """A file of an earlier run in --out: its summary, figures, method CSVs, and the animations
    `acroboter animate` wrote there by default (they show the earlier run)."""
    stem = path.stem
    method = stem in ("mlm", "penalty") or (stem.startswith("iterative-") and stem[10:].isdigit())
    animation = stem.startswith("animation_") and path.suffix in (".mp4", ".gif")
    return path.name == "summary.json" or path.name in FIGURES or (path.suffix == ".csv" and method) or animation


def _staging_folder(out: Path) -> Path:
    """A temporary folder inside --out for this run's files (proves --out writable before any work)."""
    out.mkdir(parents=True, exist_ok=True)
    return Path(tempfile.mkdtemp(prefix=".run-", dir=out))


def _publish(staging: Path, out: Path) -> None:
    """Replace the earlier run's files in --out with this run's: figures and CSVs first, summary last.
    Ctrl-C waits for the few renames (deferred_interrupt), so --out is never left half-replaced."""
    with deferred_interrupt():
        for old in out.iterdir():
            if old.is_file() and _is_run_file(old):
                old.unlink()
        new = sorted(staging.iterdir(), key=lambda p: p.name == "summary.json")
        for path in new:
            os.replace(path, out / path.name)
        staging.rmdir()


@guarded
def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    # as typed: `acroboter run ...` (console script, python -m acroboter) or `python -m acroboter.run ...`
    via_cli = Path(sys.argv[0]).name in ("acroboter", "__main__.py")
    prefix = ["acroboter", "run"] if via_cli else ["python", "-m", "acroboter.run"]
    args.command_line = [*prefix, *(sys.argv[1:] if argv is None else argv)]
    if getattr(args, "view_problem", None):  # before any work: the run would end in a window that cannot open
        print(f"error: {args.view_problem}", file=sys.stderr)
        return 3
    existed = args.out.exists()
    try:
        staging = _staging_folder(args.out)
    except OSError as err:
        print(f"error: cannot write results into --out {args.out}: {err.strerror or err}", file=sys.stderr)
        return 2
    try:
        return _run(args, staging)
    except KeyboardInterrupt:
        earlier = f"the earlier ones in {args.out} are as they were" if existed else f"{args.out} was not created"
        print(f"interrupted: no results written ({earlier})", file=sys.stderr)
        return 130
    finally:
        shutil.rmtree(staging, ignore_errors=True)  # gone already when the results were published
        if not existed and args.out.is_dir() and not any(args.out.iterdir()):
            args.out.rmdir()  # a run that wrote nothing leaves no empty folder it made


def _run(args: argparse.Namespace, staging: Path) -> int:
    # Imports after parsing: --help stays instant.
    import numpy as np
    from tqdm import tqdm

    from ..api.crane import Crane
    from ..control.controllers import SingularSystemError
    from ..control.recovery import RecoveryError
    from ..model.physical import PlantParameterError, with_parameters
    from ..model.spec import SpecError
    from ..report.report import format_table, write_figures, write_summary
    from ..runtime.compiled import StaleModelError
    from ..sim.plant import SimulationError
    from ..sim.simulation import check_mujoco_timestep
    from ..sim.statics import EquilibriumError

    overrides = {name: getattr(args, name) for name in
                 ("kp", "kd", "alpha_geometric", "alpha_servo", "omega", "mu", "recovery", "kappa", "ki")}
    try:
        crane = Crane.from_toml(args.spec, cache_dir=args.cache_dir)
        spec = crane.spec
        with_parameters(spec, args.plant_params)  # names and values checked before any work (exit 2)
        if args.mujoco_timestep is not None:
            try:
                check_mujoco_timestep(spec.simulation.step, args.mujoco_timestep)
            except ValueError as err:
                print(f"error: --{str(err).replace('_', '-', 1)}", file=sys.stderr)
                return 2
        sensing = crane.sensing(args.sensing)  # SpecError naming the field (exit 2), before any work
        methods = expand_methods(args.method, args.iterations or spec.controller.penalty.iterations)
        try:
            gains = crane.gains(**overrides)
        except ValueError as err:  # e.g. --ki past the stability bound of the spec's (or given) kp, kd
            print(f"error: {err}", file=sys.stderr)
            return 2
        path = crane.path
        start = crane.equilibrium()
        duration = args.duration if args.duration is not None else path.duration
        rate, step = spec.controller.rate_hz, spec.simulation.step
        steps = int(round(duration * rate))
        if not 1 <= steps <= MAX_CONTROL_STEPS:
            print(f"error: --duration {duration:g} s is {steps} control steps at {rate:g} Hz: give between one "
                  f"({1 / rate:g} s) and {MAX_CONTROL_STEPS} ({MAX_CONTROL_STEPS / rate:g} s)", file=sys.stderr)
            return 2
        results, summaries, warnings = {}, {}, []
        # Before the run: can the path be followed within the limits at all?
        feasibility = crane.check_path(duration, **overrides)
        if feasibility.feasible is False:
            warnings.append(f"the desired path is {feasibility.message}")
        with tqdm(total=steps * len(methods), unit="step", disable=progress_disabled(args.quiet),
                  desc="simulating", file=sys.stderr) as bar:
            for method in methods:
                bar.set_postfix_str(method)
                try:
                    r = crane.simulate(method, duration=duration, progress=bar.update,
                                       plant_params=args.plant_params, sensing=sensing or False, plant=args.plant,
                                       mujoco_timestep=args.mujoco_timestep, **overrides)
                except (SingularSystemError, RecoveryError, SimulationError) as err:
                    # This method cannot handle this system (e.g. MLM and redundant constraints), or
                    # failed at its first step: say why, and go on with the others.
                    summaries[method] = {"error": str(err)}
                    warnings.append(f"{method} cannot run on this spec: {err}")
                    bar.update(steps)
                    continue
                results[method] = r
                summaries[method] = r.summary()
                if r.diverged_at is not None:
                    warnings.append(f"{method} diverged at t = {r.diverged_at:.2f} s: {r.run.divergence}")
                    bar.update(steps - len(r.time) + 1)
                for cable, c in summaries[method]["cables"].items():  # the plant's cables, not the inputs
                    if c["time_slack_s"] > 0 or c["transitions"] > 0:
                        warnings.append(f"{method}: cable {cable} was slack for {c['time_slack_s']:.3g} s "
                                        f"({c['transitions']} slack/taut transitions)")
    except (SpecError, StaleModelError, EquilibriumError, PlantParameterError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 3

    if not results:  # nothing to show: the earlier results in --out stay as they were
        for w in warnings:
            print(f"warning: {w}", file=sys.stderr)
        print("error: no method could run on this spec (see the warnings above); nothing was written",
              file=sys.stderr)
        return 3
    args.sensing_used = sensing
    out: Path = staging  # published into args.out at the end, in one go
    paper = is_paper_crane(spec)
    for name, r in results.items():
        r.to_csv(out / f"{name}.csv", state=args.state)
    limits = input_limits_summary(spec, crane.layout)
    write_summary(out / "summary.json", spec.name, summaries, duration, warnings,
                  extra={"input_limits": limits, "path_feasibility": feasibility.to_dict(),
                         "provenance": provenance(args, spec, gains, methods, duration)})
    if not args.no_plots:
        lay = crane.layout
        input_labels = [f"{name} [{unit}]" for name, unit in zip(lay.inputs, lay.input_units, strict=True)]
        write_figures(out, {m: r.run for m, r in results.items()}, crane.scenario,
                      {m: s for m, s in summaries.items() if m in results},
                      input_labels, lay.servo_constraints, input_limits=spec.input_limits()[:2], paper=paper)
    _publish(staging, args.out)
    # Printed once the results are in place: a table on screen always has its files.
    engine = plant_provenance(args, spec)
    plant_text = (f"plant RK4 h = {step * 1e3:g} ms" if engine["engine"] == "own" else
                  f"plant MuJoCo {engine['mujoco_version']} RK4 h = {engine['step_s'] * 1e3:g} ms")
    print(f"spec {spec.name}: {duration:g} s at {rate:g} Hz, {plant_text}; "
          f"start tensions {np.array2string(start.inputs, precision=4)}")
    if args.plant_params:
        print("plant differs from the model: " + ", ".join(f"{k}={v:g}" for k, v in args.plant_params.items()))
    if sensing is not None:
        print("controller measures (docs/sensing.md): " + "; ".join(
            f"{g.name} noise {g.noise:g}" + (f" step {g.quantization:g}" if g.quantization else "")
            for g in sensing.groups) + f"; delay {sensing.delay_periods} period(s), seed {sensing.seed}")
    print(format_table(summaries, paper=paper))
    if engine["engine"] == "mujoco":
        print("step times with --plant mujoco are of a cold cache (MuJoCo's steps run between two control steps): "
              "time the controllers on the own plant or with `acroboter bench` (docs/mujoco.md)")
    for w in warnings:
        print(f"warning: {w}")
    print(f"results in {args.out}/")
    if args.view:
        from ..report.viewer import replay

        replay(crane.model, crane.path, results)
    saturated = [m for m, s in summaries.items() if s.get("saturated")]
    if feasibility.feasible is False or saturated:
        if feasibility.feasible is False:
            reason = feasibility.message.removeprefix("not feasible with these limits: ")
        elif feasibility.feasible is None:
            reason = f"the check before the run could not decide ({feasibility.message})"
        else:
            reason = "the check before the run found the ideal motion feasible, but the closed loop needed more"
        held = f"; saturated: {', '.join(saturated)}" if saturated else ""
        print(f"the path was not feasible with these limits: {reason}{held}")
    return 0


def provenance(args: argparse.Namespace, spec, gains, methods: list[str], duration: float) -> dict:
    """What made this run: enough to repeat it (spec content, every setting, versions, command line)."""
    import datetime
    import hashlib
    import platform
    from dataclasses import asdict
    from importlib import metadata

    import casadi

    try:
        version = metadata.version("acroboter")
    except metadata.PackageNotFoundError:
        version = "unknown"
    return {
        "spec_file": str(args.spec),
        "spec_sha256": hashlib.sha256(Path(args.spec).read_bytes()).hexdigest(),
        "spec_model_hash": spec.model_hash(),
        # the spec itself: the folder can be re-run or drawn after the file has moved or changed
        "spec_toml": Path(args.spec).read_text(),
        "gains": asdict(gains),
        "plant": plant_provenance(args, spec),
        # the plant's physical parameters other than the spec's (acroboter.physical), {} for none
        "plant_params": dict(getattr(args, "plant_params", {})),
        # what the controller measured instead of the plant's state (docs/sensing.md), None for the state
        "sensing": sensing.model_dump(mode="json") if (sensing := getattr(args, "sensing_used", None)) else None,
        "methods": methods,
        "duration_s": duration,
        "rate_hz": spec.controller.rate_hz,
        "plant_step_s": spec.simulation.step,
        "acroboter_version": version,
        "casadi_version": casadi.__version__,
        "python": platform.python_version(),
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "command_line": args.command_line,
    }


def plant_provenance(args: argparse.Namespace, spec) -> dict:
    """Which engine simulated the crane, and at what step."""
    if getattr(args, "plant", "own") != "mujoco":
        return {"engine": "own", "integrator": "RK4 with Baumgarte stabilisation", "step_s": spec.simulation.step}
    from importlib import metadata

    from ..model.mjcf_model import DEFAULT_TIMESTEP

    return {"engine": "mujoco", "mujoco_version": metadata.version("mujoco"), "integrator": "RK4",
            "step_s": args.mujoco_timestep or DEFAULT_TIMESTEP, "model": "acroboter.mjcf_model (docs/mujoco.md)"}


def is_paper_crane(spec) -> bool:
    """The paper's crane (its MATLAB times and bounds apply): the shipped example's model."""
    from ..model.spec import load_spec

    return spec.model_hash() == load_spec(example_spec("acroboter")).model_hash()


def input_limits_summary(spec, layout) -> dict:
    """Each input's resolved [min, max] and preferred value (null: unbounded on that side)."""
    lower, upper, preferred = spec.input_limits()

    def finite(v: float):
        return float(v) if math.isfinite(v) else None

    return {name: {"min": finite(lo), "max": finite(hi), "preferred": float(p), "unit": unit}
            for name, unit, lo, hi, p in zip(layout.inputs, layout.input_units, lower, upper, preferred, strict=True)}


if __name__ == "__main__":
    sys.exit(main())

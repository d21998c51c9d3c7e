"""Run the paper's scenario: `acroboter run` (or `python -m acroboter.run`; see --help).

A thin layer over the library (acroboter.Crane.simulate): what it prints and writes is what
`crane.simulate(method, duration=..., **settings).summary()` gives for the same options. The options
and their checks are acroboter.cli.run_args; here: the run, its outputs (written into a staging folder
and published whole) and their provenance.

With no arguments: the default spec, MLM, Penalty and Iterative Penalty with the spec's iteration
counts (3, 4, 5), the full path; a table on stdout and results/ with summary.json, one CSV per
method and the figures.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path

from ..model.controller_parameters import OVERRIDES
from ..model.spec import MAX_CONTROL_STEPS
from ..process.interrupts import exit_status
from ..process.locations import example_spec
from .entry import as_option_text, guarded, progress_disabled
from .outputs import FAILED, ResultsFolder, results_folder
from .run_args import expand_methods, parse_args

FIGURES = ("path_3d.png", "tracking_errors.png", "servo_errors.png", "inputs.png", "control_step_time.png")


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
    folder = None
    try:
        # --out checked now (exit 2); the results are staged and swapped in at the end (docs/run.md). The
        # videos `acroboter animate` wrote into this folder show the earlier run: they go with its files.
        with results_folder(args.out, "run", expected=["summary.json"], replaces=("animate",)) as folder:
            return _run(args, folder)
    except KeyboardInterrupt as err:  # also SIGTERM, SIGHUP (acroboter.process.interrupts)
        if folder is not None and folder.published:  # Ctrl-C during the swap: held back until it was done
            print(f"interrupted (the results in {args.out} are complete: they were in place first)", file=sys.stderr)
            return exit_status(err)
        earlier = f"the earlier ones in {args.out} are as they were" if existed else f"{args.out} was not created"
        print(f"interrupted: no results written ({earlier})", file=sys.stderr)
        return exit_status(err)


class _Refused(Exception):
    """A run that cannot be done as asked: `text` (printed as 'error: …') and the exit status."""

    def __init__(self, text: str, status: int = 2):
        super().__init__(text)
        self.status = status


@dataclass
class _Setup:
    """Everything a run was checked to need, before any simulation."""

    crane: object
    trajectory: object
    sensing: object
    methods: list[str]
    gains: object
    path: object
    duration: float
    steps: int
    overrides: dict
    start: object = None
    feasibility: object = None
    warnings: list[str] = field(default_factory=list)


def _run(args: argparse.Namespace, folder: ResultsFolder) -> int:
    """The run's phases: checked (every option and the spec, before any work), simulated (each method), written
    (staged, then published in one go), reported (the table on screen, the exit status)."""
    from ..control.path import TrajectoryError
    from ..model.physical import PlantParameterError
    from ..model.spec import SpecError
    from ..runtime.compiled import StaleModelError
    from ..sim.statics import EquilibriumError

    try:
        setup = _checked(args, folder)
        results, summaries = _simulated(args, setup)
    except _Refused as refused:
        print(f"error: {refused}", file=sys.stderr)
        return refused.status
    except (SpecError, StaleModelError, EquilibriumError, PlantParameterError, TrajectoryError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 3
    if not results:  # nothing to show: the earlier results in --out stay as they were
        for w in setup.warnings:
            print(f"warning: {w}", file=sys.stderr)
        print("error: no method could run (see the warnings above); nothing was written",
              file=sys.stderr)
        return 3
    diverged = [f"{m} diverged at t = {r.diverged_at:.2f} s: {r.run.divergence}" for m, r in results.items()
                if r.diverged_at is not None]
    where = _written(args, folder, setup, results, summaries, "; ".join(diverged) or None)
    return _reported(args, setup, results, summaries, where)


def _checked(args: argparse.Namespace, folder: ResultsFolder) -> _Setup:
    """The crane, its inputs and every option checked against the spec, before any simulation (_Refused: exit 2)."""
    from ..api.crane import Crane
    from ..control.trajectory_file import read_trajectory_csv
    from ..model.physical import with_parameters
    from ..model.ranges import delay_problem
    from ..sim.simulation import check_mujoco_timestep

    overrides = {name: getattr(args, name) for name in OVERRIDES}
    crane = Crane.from_toml(args.spec, cache_dir=args.cache_dir)
    spec = crane.spec
    trajectory = read_trajectory_csv(args.trajectory) if args.trajectory is not None else None
    with_parameters(spec, args.plant_params)  # names and values checked before any work (exit 2)
    if args.mujoco_timestep is not None:
        try:
            check_mujoco_timestep(spec.simulation.step, args.mujoco_timestep, 1.0 / spec.controller.rate_hz)
        except ValueError as err:
            raise _Refused(as_option_text(err)) from None
    sensing = _checked_sensing(crane, args.sensing)  # exit 2 naming the option (or the spec's field), before any work
    methods = expand_methods(args.method, args.iterations or spec.controller.penalty.iterations)
    # a file of the user's under a result's name: refused now, before the simulation (exit 2)
    folder.claim([f"{m}.csv" for m in methods] + ([] if args.no_plots else list(FIGURES)))
    try:
        gains = crane.gains(**overrides)
    except ValueError as err:  # e.g. --kd outside what the control rate samples, --ki past Routh–Hurwitz
        raise _Refused(as_option_text(err)) from None
    path = crane.desired(trajectory)
    duration = args.duration if args.duration is not None else path.duration
    rate = spec.controller.rate_hz
    steps = int(round(duration * rate))
    if not 1 <= steps <= MAX_CONTROL_STEPS:
        raise _Refused(f"--duration {duration:g} s is {steps} control steps at {rate:g} Hz: give between one "
                       f"({1 / rate:g} s) and {MAX_CONTROL_STEPS} ({MAX_CONTROL_STEPS / rate:g} s)")
    if sensing and (problem := delay_problem(sensing.delay_periods, rate, duration)) is not None:
        given = isinstance(args.sensing, dict) and "delay_periods" in args.sensing
        where = "--sensing-delay" if given else "sensing.delay_periods (the spec's)"
        raise _Refused(f"{where}: {problem}")
    return _Setup(crane, trajectory, sensing, methods, gains, path, duration, steps, overrides,
                  warnings=[f"spec: {w}" for w in crane.warnings])


# The sensing fields the --sensing-* options override (acroboter.cli.run_args), by the option that gives them.
SENSING_OPTIONS = {"noise": "--sensing-noise", "quantization": "--sensing-quantization",
                   "delay_periods": "--sensing-delay", "seed": "--sensing-seed"}


def _checked_sensing(crane, overrides):
    """The run's sensing; a problem in what the --sensing-* options gave is named by the option (it was reported as
    an invalid spec file), one in the spec's own [sensing] section by the spec's field."""
    from ..model.spec import SpecError

    try:
        return crane.sensing(overrides)
    except SpecError as err:
        given = overrides if isinstance(overrides, dict) else {}
        lines = []
        for path, problem in err.problems:
            parts = path.split(".")
            field = parts[1] if len(parts) > 1 and parts[0] == "sensing" else None
            if field not in given or field not in SENSING_OPTIONS:
                raise  # the spec's own section: the spec's field names it
            option = SENSING_OPTIONS[field] + (f" {parts[2]}" if len(parts) > 2 else "")
            lines.append(f"{option}: {problem}")
        raise _Refused("; ".join(lines)) from None


def _simulated(args: argparse.Namespace, setup: _Setup) -> tuple[dict, dict]:
    """Each method's run ({method: Result}) and summary ({method: figures or its error}); the warnings in setup."""
    from tqdm import tqdm

    from ..control.controllers import SingularSystemError
    from ..control.recovery import RecoveryError
    from ..sim.plant import SimulationError
    from ..sim.sensing import SensingError

    crane, steps, warnings = setup.crane, setup.steps, setup.warnings
    setup.start = crane.equilibrium(setup.trajectory)
    # Before the run: can the path be followed within the limits at all?
    setup.feasibility = crane.check_path(setup.duration, trajectory=setup.trajectory, **setup.overrides)
    if setup.feasibility.feasible is False:
        warnings.append(f"the desired path is {setup.feasibility.message}")
    results, summaries = {}, {}
    with tqdm(total=steps * len(setup.methods), unit="step", disable=progress_disabled(args.quiet),
              desc="simulating", file=sys.stderr) as bar:
        for method in setup.methods:
            bar.set_postfix_str(method)
            try:
                r = crane.simulate(method, duration=setup.duration, trajectory=setup.trajectory, progress=bar.update,
                                   plant_params=args.plant_params, sensing=setup.sensing or False, plant=args.plant,
                                   mujoco_timestep=args.mujoco_timestep, fast=args.fast, **setup.overrides)
            except (SingularSystemError, RecoveryError, SimulationError) as err:
                # This method cannot handle this system (e.g. MLM and redundant constraints), or
                # failed at its first step: say why, and go on with the others.
                summaries[method] = {"error": str(err)}
                cause = "with this sensing" if isinstance(err, SensingError) else "on this spec"
                warnings.append(f"{method} cannot run {cause}: {err}")
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
    return results, summaries


def _written(args: argparse.Namespace, folder: ResultsFolder, setup: _Setup, results: dict, summaries: dict,
             failure: str | None) -> Path:
    """The CSVs, summary.json and the figures, staged and published into --out in one go; a run in which a method
    diverged (`failure`, exit 3) into --out/failed/run/ instead: the last good results stay as they were. Returns
    the folder they are in."""
    from ..report.report import write_figures, write_summary

    args.sensing_used = setup.sensing
    spec, lay = setup.crane.spec, setup.crane.layout
    out: Path = folder.staging
    for name, r in results.items():
        r.to_csv(out / f"{name}.csv", state=args.state)
    write_summary(out / "summary.json", spec.name, summaries, setup.duration, setup.warnings,
                  extra={"input_limits": input_limits_summary(spec, lay),
                         "path_feasibility": setup.feasibility.to_dict(),
                         "provenance": provenance(args, spec, setup.gains, setup.methods, setup.duration,
                                                                   setup.crane)})
    if not args.no_plots:
        input_labels = [f"{name} [{unit}]" for name, unit in zip(lay.inputs, lay.input_units, strict=True)]
        write_figures(out, {m: r.run for m, r in results.items()}, setup.crane.scenario,
                      {m: s for m, s in summaries.items() if m in results},
                      input_labels, lay.servo_constraints, input_limits=spec.input_limits()[:2],
                      paper=is_paper_crane(spec))
    if failure is None:
        folder.publish()
        return args.out
    folder.publish_failed(failure)
    return args.out / FAILED / "run"


def _reported(args: argparse.Namespace, setup: _Setup, results: dict, summaries: dict, where: Path) -> int:
    """The run on screen, printed once the results are in place (a table on screen always has its files), and the
    exit status: 3 when a method diverged (its results up to there are written)."""
    import numpy as np

    from ..report.report import format_table

    spec, sensing = setup.crane.spec, setup.sensing
    engine = plant_provenance(args, spec, setup.crane)
    plant_text = (f"plant RK4 h = {spec.simulation.step * 1e3:g} ms" if engine["engine"] == "own" else
                  f"plant MuJoCo {engine['mujoco_version']} RK4 h = {engine['step_s'] * 1e3:g} ms "
                  f"({engine['step_chosen_by']}; expected within {engine['expected_error_m'] * 1e6:.3g} µm of the "
                  "own plant)")
    print(f"spec {spec.name}: {setup.duration:g} s at {spec.controller.rate_hz:g} Hz, {plant_text}; "
          f"start tensions {np.array2string(setup.start.inputs, precision=4)}")
    if args.plant_params:
        print("plant differs from the model: " + ", ".join(f"{k}={v:g}" for k, v in args.plant_params.items()))
    if sensing is not None:
        print("controller measures (docs/sensing.md): " + "; ".join(
            f"{g.name} noise {g.noise:g}" + (f" step {g.quantization:g}" if g.quantization else "")
            for g in sensing.groups) + f"; delay {sensing.delay_periods} period(s), seed {sensing.seed}")
    print(format_table(summaries, paper=is_paper_crane(spec)))
    if engine["engine"] == "mujoco":
        print("step times with --plant mujoco are of a cold cache (MuJoCo's steps run between two control steps): "
              "time the controllers on the own plant or with `acroboter bench` (docs/mujoco.md)")
    for w in setup.warnings:
        print(f"warning: {w}")
    if where == args.out:
        print(f"results in {args.out}/")
    else:
        print(f"the failed run's records in {where}/ ({where}/failure.txt says why); the results in {args.out}/ are "
              "those of its last good run, as they were")
    if args.view:
        from ..report.viewer import replay

        replay(setup.crane.model, setup.path, results)
    _say_feasibility(setup.feasibility, [m for m, s in summaries.items() if s.get("saturated")])
    diverged = [m for m, r in results.items() if r.diverged_at is not None]
    for m in diverged:  # the results up to there are written; the run did not do what was asked
        print(f"error: {m} diverged at t = {results[m].diverged_at:.2f} s: {results[m].run.divergence}",
              file=sys.stderr)
    return 3 if diverged else 0


def _say_feasibility(feasibility, saturated: list[str]) -> None:
    """One line when the path was not feasible within the limits, or a method saturated: why."""
    if not (feasibility.feasible is False or saturated):
        return
    if feasibility.feasible is False:
        reason = feasibility.message.removeprefix("not feasible with these limits: ")
    elif feasibility.feasible is None:
        reason = f"the check before the run could not decide ({feasibility.message})"
    else:
        reason = "the check before the run found the ideal motion feasible, but the closed loop needed more"
    held = f"; saturated: {', '.join(saturated)}" if saturated else ""
    print(f"the path was not feasible with these limits: {reason}{held}")


def provenance(args: argparse.Namespace, spec, gains, methods: list[str], duration: float, crane=None) -> dict:
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
    spec_bytes = Path(args.spec).read_bytes()  # read once: the text is the hashed bytes (no newline translation)
    return {
        "spec_file": str(args.spec),
        "spec_sha256": hashlib.sha256(spec_bytes).hexdigest(),
        "spec_model_hash": spec.model_hash(),
        # the spec itself (UTF-8, as TOML is): the folder can be re-run or drawn after the file has moved or
        # changed; `animate` checks it against spec_sha256
        "spec_toml": spec_bytes.decode("utf-8"),
        "gains": asdict(gains),
        "plant": plant_provenance(args, spec, crane),
        # the plant's physical parameters other than the spec's (acroboter.model.physical), {} for none
        "plant_params": dict(getattr(args, "plant_params", {})),
        # what the controller measured instead of the plant's state (docs/sensing.md), None for the state
        "sensing": sensing.model_dump(mode="json") if (sensing := getattr(args, "sensing_used", None)) else None,
        "methods": methods,
        # the controllers' path: the reference per-term step, or the fast path (--fast, docs/fast-path.md)
        "controller_path": "fast" if getattr(args, "fast", False) else "reference",
        "duration_s": duration,
        # the trajectory file flown instead of the spec's waypoints (None: the waypoints)
        "trajectory_file": None if getattr(args, "trajectory", None) is None else str(args.trajectory),
        "rate_hz": spec.controller.rate_hz,
        "plant_step_s": spec.simulation.step,
        "acroboter_version": version,
        "casadi_version": casadi.__version__,
        "python": platform.python_version(),
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "command_line": args.command_line,
    }


def plant_provenance(args: argparse.Namespace, spec, crane=None) -> dict:
    """Which engine simulated the crane, and at what step: with MuJoCo, the crane's own step (the rule of
    acroboter.sim.mujoco_step) or the one forced by --mujoco-timestep, and how far off it is expected to be."""
    if getattr(args, "plant", "own") != "mujoco":
        return {"engine": "own", "integrator": "RK4 with Baumgarte stabilisation", "step_s": spec.simulation.step}
    from importlib import metadata

    from ..sim.mujoco_step import STEP_ERROR_BOUND_M, crane_step, expected_error

    rule, acceleration = crane_step(crane.model, crane.equilibrium())
    step = args.mujoco_timestep or rule
    return {"engine": "mujoco", "mujoco_version": metadata.version("mujoco"), "integrator": "RK4",
            "step_s": step, "step_chosen_by": "--mujoco-timestep" if args.mujoco_timestep else "the crane's rule",
            "rule_step_s": rule, "largest_cable_acceleration_m_s2": acceleration,
            # the bodies' excess over the own plant at this step: the envelope of the cranes measured (docs/mujoco.md)
            "expected_error_m": expected_error(acceleration, step), "rule_error_bound_m": STEP_ERROR_BOUND_M,
            "model": "acroboter.model.mjcf_model (docs/mujoco.md)"}


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

"""The options of `acroboter run` (see acroboter.cli.run): parsed and checked before any work, so a bad
value is one line and exit 2, never a traceback halfway through a run."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from ..model.extras import require
from ..model.locations import example_spec
from ..model.spec import MAX_ITERATIONS
from .entry import name_value, number, positive, spec_file
from .outputs import out_path

DEFAULT_SPEC = example_spec("acroboter")


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="acroboter run",
        description="Simulate the crane under the inverse-dynamics controllers and report tracking and timing.",
    )
    p.add_argument("--spec", type=spec_file, default=DEFAULT_SPEC,
                   help="model spec: a TOML file or an example's name (acroboter examples) (default: %(default)s)")
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
    p.add_argument("--out", type=out_path, default=Path("results"), help="output folder (default: %(default)s)")
    p.add_argument("--state", action="store_true",
                   help="add the rates q̇ of the natural coordinates to each CSV (q is always there)")
    p.add_argument("--cache-dir", type=Path, default=None,
                   help="where compiled models are cached (default: $ACROBOTER_CACHE_DIR, else the per-user cache)")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar (the same as `acroboter -q run`)")
    args = p.parse_args(argv)
    if args.mujoco_timestep is not None and args.plant != "mujoco":
        p.error("--mujoco-timestep needs --plant mujoco")
    # the optional extras (MissingExtraError: one line with the `pip install`, exit 2), before any work
    if args.plant == "mujoco":
        require("mujoco", "--plant mujoco", "the default --plant own needs no extra")
    if args.view:
        require("mujoco", "--view (MuJoCo's viewer)", "leave out --view, or make a video with `acroboter animate`")
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

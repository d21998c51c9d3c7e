"""The options of `acroboter run` (see acroboter.cli.run): parsed and checked before any work, so a bad
value is one line and exit 2, never a traceback halfway through a run."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..model.controller_parameters import PARAMETERS
from ..model.ranges import (
    DELAY,
    DURATION,
    ITERATIONS,
    MUJOCO_TIMESTEP,
    NOISE,
    QUANTIZATION,
    SEED,
)
from ..model.spec import MAX_ITERATIONS
from ..process.extras import require
from ..process.locations import example_spec
from .entry import add_parameter_options, named_number, ranged, ranged_list, spec_file
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
    p.add_argument("--iterations", type=ranged_list(ITERATIONS), default=None,
                   help="iteration counts for 'iterative', comma-separated, 1..1000 (default: from the spec)")
    add_parameter_options(p, [item for item in PARAMETERS if item.option])  # --kp, --kd, ... --saturation
    p.add_argument("--plant-param", action="append", default=[], metavar="NAME=VALUE", dest="plant_param",
                   type=named_number(None, "SU.mass=8.8"),
                   help="a physical parameter of the plant other than the spec's (the controller keeps the spec's), "
                        "e.g. SU.mass=8.8; repeatable; names: gravity.z, <body>.mass, <body>.inertia.xx, "
                        "<body>.damping.translational, <body>.points.<point>.x, <cable>.length, "
                        "<cable>.winch.reflected_inertia (docs/model.md, 'A plant that differs from the model'); "
                        "each within its spec field's range (docs/spec.md)")
    p.add_argument("--sensing-noise", action="append", default=[], metavar="GROUP=STD",
                   type=named_number(NOISE, "positions=0.0002", "GROUP=STD"),
                   help="the controller measures instead of reading the plant's state: Gaussian noise (standard "
                        "deviation, m or unitless) of a sensing group, e.g. positions=0.0002; repeatable; groups: the "
                        "spec's [sensing] ones, else positions, axes, lengths, at most 1 (docs/sensing.md)")
    p.add_argument("--sensing-quantization", action="append", default=[], metavar="GROUP=STEP",
                   type=named_number(QUANTIZATION, "lengths=0.0001", "GROUP=STEP"),
                   help="quantisation step of a sensing group (m or unitless), e.g. lengths=0.0001; repeatable")
    p.add_argument("--sensing-delay", type=ranged(DELAY), default=None, metavar="N",
                   help="measurement delay in whole control periods, shorter than the run (default: the spec's, "
                        "else 0)")
    p.add_argument("--sensing-seed", type=ranged(SEED), default=None, metavar="N",
                   help="seed of the measurement noise (default: spec, 0)")
    p.add_argument("--no-sensing", action="store_true",
                   help="ignore the spec's [sensing] section: the controller reads the plant's state")
    p.add_argument("--plant", choices=["own", "mujoco"], default="own",
                   help="the crane the controllers drive: own (the project's Baumgarte RK4 plant) or mujoco (MuJoCo "
                        "on the spec's MJCF model, docs/mujoco.md) (default: %(default)s)")
    p.add_argument("--mujoco-timestep", type=ranged(MUJOCO_TIMESTEP), default=None, metavar="S",
                   help="MuJoCo's time step with --plant mujoco, dividing the spec's plant step, at most 100,000 per "
                        "control period (default: 0.0001)")
    p.add_argument("--view", action="store_true",
                   help="after the run, replay it in MuJoCo's interactive viewer (needs a display)")
    p.add_argument("--duration", type=ranged(DURATION), default=None,
                   help="simulated seconds (default: the whole path)")
    p.add_argument("--trajectory", type=Path, default=None, metavar="FILE",
                   help="fly this trajectory file instead of the spec's waypoints (CSV: t_s, x_m, y_m, z_m, vx_m_s, "
                        "vy_m_s, vz_m_s, ax_m_s2, ay_m_s2, az_m_s2 and optionally yaw_rad, yaw_rate_rad_s, "
                        "yaw_acc_rad_s2; what `acroboter plan` writes, docs/planning.md)")
    p.add_argument("--out", type=out_path, default=Path("results"), help="output folder (default: %(default)s)")
    p.add_argument("--state", action="store_true",
                   help="add the rates q̇ of the natural coordinates to each CSV (q is always there)")
    p.add_argument("--cache-dir", type=Path, default=None,
                   help="where compiled models are cached (default: $ACROBOTER_CACHE_DIR, else the per-user cache)")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    p.add_argument("--fast", action="store_true",
                   help="the controllers' fast path: one compiled function per control step, compiled into the cache "
                        "on first use of a method (docs/controller.md); default: the reference per-term path")
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
    for name, value in args.plant_param:  # each value's range is its spec field's: checked with the spec
        if name in args.plant_params:
            p.error(f"--plant-param {name} given twice")
        args.plant_params[name] = value
    args.sensing = _sensing_overrides(p, args)
    try:
        if args.method is not None and not expand_methods(args.method, args.iterations or [1]):
            p.error(f"--method names no method, found {args.method}")
    except ValueError as err:
        p.error(str(err))
    return args


def _sensing_overrides(p: argparse.ArgumentParser, args: argparse.Namespace):
    """The --sensing-* options as Crane.simulate(sensing=...) takes them (None: the spec's section,
    False: none). Each number is in its range already; the groups' names are checked by the sensing model (a
    SpecError naming the field, exit 2), the delay against the run's length by `acroboter.cli.run`."""
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
        for group, value in option:
            overrides.setdefault(key, {})[group] = value
    for value, key in ((args.sensing_delay, "delay_periods"), (args.sensing_seed, "seed")):
        if value is not None:
            overrides[key] = value
    return overrides


def expand_methods(requested: list[str] | None, iterations: list[int]) -> list[str]:
    names = []
    for item in requested or ["mlm", "penalty", "iterative"]:
        names += [m.strip() for m in item.split(",")]
    if not all(names):  # `mlm,,` or `mlm,`: a method left out, or a typo
        raise ValueError(f"expected comma-separated methods (mlm, penalty, iterative or iterative-N), found an "
                         f"empty item in '{','.join(requested or [])}'")
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

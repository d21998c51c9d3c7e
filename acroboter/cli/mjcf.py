"""`python -m acroboter.mjcf SPEC -o crane.xml` (or `acroboter mjcf`): the MJCF model of a spec.

    acroboter mjcf model_spec/lab_crane.toml -o lab_crane.xml
    python -m mujoco.viewer --mjcf lab_crane.xml          # where a display exists

The XML is what acroboter.model.mjcf_model writes (docs/mujoco.md: every modelling choice); before it is
written, MuJoCo loads it (`mujoco.MjModel.from_xml_string`), so a file on disk always loads. By
default its reference pose is the crane's static equilibrium at the start of the path, with a
keyframe `static_start` whose ctrl holds it there (load it in MuJoCo's viewer: without the inputs
the winches pay out and the load falls); `--pose spec` writes the spec's initial configuration
instead, which is the XML checked in as generated/<spec>/<spec>.xml for the specs in model_spec/.
A static start that needs an input beyond its limits (a winch that would have to push, or pull harder than
its max) is written as it is, with a warning on stderr, as `acroboter run` warns: MuJoCo clamps the
keyframe's ctrl to the actuator's ctrlrange, so the crane does not stay in that pose.
It needs the mujoco extra (pip install 'acroboter[mujoco]'); without it, it says so before any work.
Into a folder (-o FOLDER, or the current folder by default) the XML follows the output-folder contract of every
command (docs/run.md): recorded in the folder's manifest, a file of yours of that name never written over.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
from pathlib import Path

from ..model.ranges import MUJOCO_TIMESTEP, mujoco_work_problem
from .entry import file_write_problem, guarded, ranged, spec_file
from .outputs import out_path, partial_path, remove_stale_partials, results_folder

TIMESTEP = dataclasses.replace(MUJOCO_TIMESTEP, name="timestep")  # --timestep: MuJoCo's step, as run's option


def xml_target(text: str) -> str:
    """-o: a folder (an existing one, or a name ending in /), a file named *.xml, or - for stdout. Any other file
    name is refused at parse time: `-o lab_crane.toml` would replace the spec itself with XML. Kept as text: the
    trailing / that says "a folder" is gone from a Path."""
    out_path(text)  # an empty name refused
    target = text.strip()
    if target == "-" or target.endswith(("/", os.sep)) or Path(target).is_dir() or Path(target).suffix == ".xml":
        return target
    raise argparse.ArgumentTypeError(f"{target}: an MJCF file is named *.xml (give crane.xml, a folder ending in /, "
                                     "or - for stdout)")


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    from ..model.mjcf_model import DEFAULT_TIMESTEP

    p = argparse.ArgumentParser(prog="acroboter mjcf", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("spec", type=spec_file, nargs="?", default=None,
                   help="model spec TOML (default: the paper's crane, model_spec/acroboter.toml)")
    p.add_argument("-o", "--out", type=xml_target, default=None,
                   help="the XML file to write (*.xml), or a folder (an existing one, or a name ending in /) to "
                        "write <spec name>.xml into (default: the current folder; - for stdout)")
    p.add_argument("--timestep", type=ranged(TIMESTEP), default=DEFAULT_TIMESTEP,
                   help="MuJoCo's time step in s, at most 100,000 per control period of the spec; the cables' "
                        "constraint time constant is two steps (default: %(default)g, where the agreement with the "
                        "own plant was measured)")
    p.add_argument("--pose", choices=["static", "spec"], default="static",
                   help="the reference pose: static (the static equilibrium at the path's start, with a keyframe "
                        "static_start holding it; compiles the crane's library on first use) or spec (the spec's "
                        "initial configuration, as in generated/) (default: %(default)s)")
    p.add_argument("-q", "--quiet", action="store_true",
                   help="print nothing but errors and warnings (on stderr)")
    return p.parse_args(argv)


@guarded
def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    from ..process.extras import require

    require("mujoco", "acroboter mjcf (MuJoCo loads the XML before it is written)",
            "acroboter.Crane.from_toml(SPEC).mjcf() writes the XML without loading it")  # exit 2, before any work
    import mujoco

    from ..model.spec import load_spec
    from ..process.locations import example_spec

    spec_path = args.spec if args.spec is not None else example_spec("acroboter")
    spec = load_spec(spec_path)
    if (problem := mujoco_work_problem(args.timestep, 1.0 / spec.controller.rate_hz)) is not None:
        print(f"error: --timestep: {problem.replace('mujoco_timestep', 'timestep')}", file=sys.stderr)
        return 2  # before any work: a model that steps that finely is no model to simulate with
    out, folder = None, None
    if args.out != "-":  # checked before any work (the static pose compiles the crane's library)
        out = Path(args.out) if args.out is not None else Path(".")
        problem = None
        if args.out is None or args.out.endswith(("/", os.sep)) or out.is_dir():  # into a folder: <spec name>.xml
            folder, out = out, out / f"{spec.name}.xml"  # made if missing, checked by results_folder
        elif out.exists() and os.path.samefile(out, spec_path):  # `mjcf s.xml -o s.xml`, or a link to the spec
            problem = f"it is the spec being read ({spec_path})"
        elif out.is_symlink():  # the link is replaced by the file, never written through (animate does the same)
            problem = file_write_problem(Path(os.path.abspath(out)).parent / "_")
        else:
            problem = file_write_problem(out)
        if problem:
            print(f"error: -o {args.out}: {problem}: give a file in a folder you can write to, or - for stdout",
                  file=sys.stderr)
            return 2
    if folder is None:
        return _write(args, spec, spec_path, out, mujoco)
    # Into a folder: the output-folder contract (docs/run.md): locked, <spec>.xml recorded in its manifest, a file
    # of that name that no earlier mjcf wrote refused before any work; each spec's XML is its own (accumulate).
    with results_folder(folder, "mjcf", option="-o", expected=[out.name], accumulate=True) as staged:
        return _write(args, spec, spec_path, out, mujoco, staged)


def _write(args: argparse.Namespace, spec, spec_path: Path, out: Path | None, mujoco, staged=None) -> int:
    """The XML on stdout (out None), into the staged folder, or into the file `out` through a temporary file."""
    from ..model.mjcf_model import mjcf_xml

    start = None
    if args.pose == "static":
        from ..api.crane import Crane
        from ..sim.statics import inputs_outside_limits

        crane = Crane.from_toml(spec_path)
        equilibrium = crane.equilibrium()
        start = (equilibrium.q, equilibrium.inputs)
        # as `acroboter run` warns (its feasibility check at t = 0): MuJoCo clamps ctrl to ctrlrange
        for problem in inputs_outside_limits(spec, crane.layout, equilibrium.inputs):
            print(f"warning: the static start is outside the input limits: {problem}; the keyframe static_start "
                  "holds that ctrl, outside the actuator's ctrlrange, which MuJoCo clamps: the crane does not stay "
                  "in that pose (`acroboter run` reports the path not feasible from t = 0)", file=sys.stderr)
    xml = mjcf_xml(spec, args.timestep, start)
    try:
        model = mujoco.MjModel.from_xml_string(xml)
    except ValueError as err:  # a model this writer should never produce: say so, write nothing
        raise RuntimeError(f"MuJoCo refused the MJCF written for {spec_path}: {err}") from err
    if out is None:  # -o -
        sys.stdout.write(xml)
        return 0
    if staged is not None:
        (staged.staging / out.name).write_text(xml)
        staged.publish()
    else:
        target = out  # a link is replaced by the file: written through, it wrote over whatever it named (a spec)
        # Written beside the target and renamed: an interrupted write never leaves half an XML; the temporary
        # file carries this process's id, and one a killed mjcf left is removed by the next write of the file.
        remove_stale_partials(target)
        tmp = None
        try:
            tmp = partial_path(target)
            with open(tmp, "x") as f:  # an ordinary new file (mode 0666 less the umask)
                f.write(xml)
            os.replace(tmp, target)
        except OSError as err:
            print(f"error: -o {args.out}: cannot write it: {err.strerror or err}", file=sys.stderr)
            return 2
        finally:
            if tmp is not None and os.path.exists(tmp):
                os.unlink(tmp)
    if not args.quiet:
        print(f"wrote {out}: {model.nbody - 1} bodies, {model.njnt} joints, {model.ntendon} tendons, "
              f"{model.nu} actuators (MuJoCo {mujoco.__version__}, time step {model.opt.timestep:g} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

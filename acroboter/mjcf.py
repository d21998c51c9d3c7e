"""`python -m acroboter.mjcf SPEC -o crane.xml` (or `acroboter mjcf`): the MJCF model of a spec.

    acroboter mjcf model_spec/lab_crane.toml -o lab_crane.xml
    python -m mujoco.viewer --mjcf lab_crane.xml          # where a display exists

The XML is what acroboter.mjcf_model writes (docs/mujoco.md: every modelling choice); before it is
written, MuJoCo loads it (`mujoco.MjModel.from_xml_string`), so a file on disk always loads. For
the specs in model_spec/ the same XML is checked in as generated/<spec>/<spec>.xml.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

from .entry import guarded, number


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    from .mjcf_model import DEFAULT_TIMESTEP, MAX_TIMESTEP

    p = argparse.ArgumentParser(prog="acroboter mjcf", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("spec", type=Path, nargs="?", default=None,
                   help="model spec TOML (default: the paper's crane, model_spec/acroboter.toml)")
    p.add_argument("-o", "--out", type=Path, default=None,
                   help="the XML file to write (default: <spec name>.xml in the current folder; - for stdout)")
    p.add_argument("--timestep", type=number(0, MAX_TIMESTEP, low_open=True), default=DEFAULT_TIMESTEP,
                   help="MuJoCo's time step in s; the cables' constraint time constant is two steps "
                        "(default: %(default)g, where the agreement with the own plant was measured)")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors")
    return p.parse_args(argv)


@guarded
def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    import mujoco

    from .locations import example_spec
    from .mjcf_model import mjcf_xml
    from .spec import load_spec

    spec_path = args.spec if args.spec is not None else example_spec("acroboter")
    spec = load_spec(spec_path)
    xml = mjcf_xml(spec, args.timestep)
    try:
        model = mujoco.MjModel.from_xml_string(xml)
    except ValueError as err:  # a model this writer should never produce: say so, write nothing
        raise RuntimeError(f"MuJoCo refused the MJCF written for {spec_path}: {err}") from err
    if str(args.out) == "-":
        sys.stdout.write(xml)
        return 0
    out = args.out if args.out is not None else Path(f"{spec.name}.xml")
    if out.is_dir():
        out = out / f"{spec.name}.xml"
    if not out.parent.is_dir():
        print(f"error: -o {out}: the folder {out.parent} does not exist", file=sys.stderr)
        return 2
    # Written beside the target and renamed: an interrupted write never leaves half an XML.
    fd, tmp = tempfile.mkstemp(prefix=f".{out.name}.", dir=out.parent)
    try:
        with os.fdopen(fd, "w") as f:
            f.write(xml)
        os.replace(tmp, out)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    if not args.quiet:
        print(f"wrote {out}: {model.nbody - 1} bodies, {model.njnt} joints, {model.ntendon} tendons, "
              f"{model.nu} actuators (MuJoCo {mujoco.__version__}, time step {model.opt.timestep:g} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

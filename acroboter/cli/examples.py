"""`acroboter examples`: the example cranes shipped with the package, one line each; any of them is a
valid `--spec NAME` (`acroboter run --spec lab_crane`), and `--path` prints where its TOML file is (a
copy to start a crane of your own from)."""

from __future__ import annotations

import argparse
import sys

from ..model.spec import load_spec
from ..process.locations import example_names, example_spec
from .entry import guarded, spec_file


@guarded
def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="acroboter examples", description=__doc__)
    p.add_argument("--path", type=spec_file, metavar="NAME", default=None,
                   help="print the path of this example's spec file instead of the list")
    args = p.parse_args(argv)
    if args.path is not None:
        print(args.path)
        return 0
    names = example_names()
    width = max(len(n) for n in names)
    for name in names:
        spec = load_spec(example_spec(name))
        print(f"{name:<{width}}  {spec.description}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

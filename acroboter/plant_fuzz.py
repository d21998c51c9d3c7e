"""`python -m acroboter.plant_fuzz`: the same as `acroboter plant-fuzz` (through the console: its -q/-v, its check of
the core dependencies, its error boundary)."""

import sys

from .cli.console import main as _console


def main(argv: list[str] | None = None) -> int:
    return _console(["plant-fuzz", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":
    sys.exit(main())

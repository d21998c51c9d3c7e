"""`python -m acroboter.robustness`: the same as `acroboter robustness` (through the console: its -q/-v, its check of
the core dependencies, its error boundary)."""

import sys

from .cli.console import main as _console


def main(argv: list[str] | None = None) -> int:
    return _console(["robustness", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":
    sys.exit(main())

"""`python -m acroboter.sweep`: the same as `acroboter sweep` (through the console: its -q/-v, its check of
the core dependencies, its error boundary)."""

import sys

from .cli.console import main as _console


def main(argv: list[str] | None = None) -> int:
    return _console(["sweep", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":
    sys.exit(main())

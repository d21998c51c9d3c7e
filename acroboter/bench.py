"""`python -m acroboter.bench`: forwards to acroboter.cli.bench (the `acroboter bench` command)."""

import sys

from .cli.bench import main

if __name__ == "__main__":
    sys.exit(main())

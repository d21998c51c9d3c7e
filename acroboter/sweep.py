"""`python -m acroboter.sweep`: forwards to acroboter.cli.sweep (the `acroboter sweep` command)."""

import sys

from .cli.sweep import main

if __name__ == "__main__":
    sys.exit(main())

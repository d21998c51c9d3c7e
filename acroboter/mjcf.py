"""`python -m acroboter.mjcf`: forwards to acroboter.cli.mjcf (the `acroboter mjcf` command)."""

import sys

from .cli.mjcf import main

if __name__ == "__main__":
    sys.exit(main())

"""`python -m acroboter.run`: forwards to acroboter.cli.run (the `acroboter run` command)."""

import sys

from .cli.run import main

if __name__ == "__main__":
    sys.exit(main())

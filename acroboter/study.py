"""`python -m acroboter.study`: forwards to acroboter.cli.study (the `acroboter study` command)."""

import sys

from .cli.study import main

if __name__ == "__main__":
    sys.exit(main())

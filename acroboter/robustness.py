"""`python -m acroboter.robustness`: forwards to acroboter.cli.robustness (the `acroboter robustness` command)."""

import sys

from .cli.robustness import main

if __name__ == "__main__":
    sys.exit(main())

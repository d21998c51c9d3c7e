"""`python -m acroboter.animate`: forwards to acroboter.cli.animate (the `acroboter animate` command)."""

import sys

from .cli.animate import main

if __name__ == "__main__":
    sys.exit(main())

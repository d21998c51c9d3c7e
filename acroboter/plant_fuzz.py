"""`python -m acroboter.plant_fuzz`: forwards to acroboter.cli.plant_fuzz (the `acroboter plant-fuzz` command)."""

import sys

from .cli.plant_fuzz import main

if __name__ == "__main__":
    sys.exit(main())

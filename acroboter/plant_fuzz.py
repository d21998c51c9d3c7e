"""`python -m acroboter.plant_fuzz` is `acroboter plant-fuzz` (the console's -q/-v, core check and error boundary)."""

import sys

from .cli.console import forward

main = forward("plant-fuzz")
if __name__ == "__main__":
    sys.exit(main())

"""`python -m acroboter.mjcf` is `acroboter mjcf` (the console's -q/-v, core check and error boundary)."""

import sys

from .cli.console import forward

main = forward("mjcf")
if __name__ == "__main__":
    sys.exit(main())

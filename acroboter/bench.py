"""`python -m acroboter.bench` is `acroboter bench` (the console's -q/-v, core check and error boundary)."""

import sys

from .cli.console import forward

main = forward("bench")
if __name__ == "__main__":
    sys.exit(main())

"""`python -m acroboter.animate` is `acroboter animate` (the console's -q/-v, core check and error boundary)."""

import sys

from .cli.console import forward

main = forward("animate")
if __name__ == "__main__":
    sys.exit(main())

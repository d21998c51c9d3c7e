"""`python -m acroboter.build` is `acroboter build` (the console's -q/-v, core check and error boundary)."""

import sys

from .cli.console import forward

main = forward("build")
if __name__ == "__main__":
    sys.exit(main())

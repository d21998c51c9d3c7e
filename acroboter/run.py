"""`python -m acroboter.run` is `acroboter run` (the console's -q/-v, core check and error boundary)."""

import sys

from .cli.console import forward

main = forward("run")
if __name__ == "__main__":
    sys.exit(main())

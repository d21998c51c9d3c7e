"""`python -m acroboter.study` is `acroboter study` (the console's -q/-v, core check and error boundary)."""

import sys

from .cli.console import forward

main = forward("study")
if __name__ == "__main__":
    sys.exit(main())

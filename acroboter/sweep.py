"""`python -m acroboter.sweep` is `acroboter sweep` (the console's -q/-v, core check and error boundary)."""

import sys

from .cli.console import forward

main = forward("sweep")
if __name__ == "__main__":
    sys.exit(main())

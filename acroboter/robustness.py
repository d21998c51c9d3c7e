"""`python -m acroboter.robustness` is `acroboter robustness` (the console's -q/-v, core check and error boundary)."""

import sys

from .cli.console import forward

main = forward("robustness")
if __name__ == "__main__":
    sys.exit(main())

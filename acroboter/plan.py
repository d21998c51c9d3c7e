"""`python -m acroboter.plan` is `acroboter plan` (the console's -q/-v, core check and error boundary)."""

import sys

from .cli.console import forward

main = forward("plan")
if __name__ == "__main__":
    sys.exit(main())

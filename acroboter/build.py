"""`python -m acroboter.build`: forwards to acroboter.runtime.build (compile the example specs' libraries)."""

import sys

from .runtime.build import main

if __name__ == "__main__":
    sys.exit(main())

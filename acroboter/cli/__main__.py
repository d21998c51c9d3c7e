"""`python -m acroboter.cli <command>`: the same as the `acroboter` console script."""

import sys

from .console import main

sys.exit(main())

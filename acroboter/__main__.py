"""`python -m acroboter <command>`: the same as the `acroboter` console script."""

import sys

from .cli.console import main

sys.exit(main())

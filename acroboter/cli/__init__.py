"""The command lines: `acroboter <command>` (console.py), the one error boundary (entry.py) and one
module per subcommand. Nothing below imports from here."""

from .console import COMMANDS, main

__all__ = ["COMMANDS", "main"]

"""`python -m scanner` runs the `scanner` command."""

import sys

from scanner.commands.main import main

sys.exit(main())

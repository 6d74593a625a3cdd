"""`python -m scanner.cli` runs the `scanner` command."""

import sys

from scanner.cli.main import main

sys.exit(main())

"""`python -m membrane_cli ...` runs the `membrane` command (for a venv without its script)."""

import sys

from membrane_cli.dispatcher import main

sys.exit(main())

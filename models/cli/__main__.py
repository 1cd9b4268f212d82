"""`python -m models.cli` runs the `magnet` command."""

import sys

from models.cli.main import main

sys.exit(main())

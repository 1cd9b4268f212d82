"""`python -m worker worker ...` = `magnet worker ...` without the package installed."""

import sys

from worker.cli import main

sys.exit(main())

"""`python -m service serve ...` = `magnet serve ...` without the package installed."""

import sys

from service.cli import main

sys.exit(main())

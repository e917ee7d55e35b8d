"""``python -m tools.tradeoff``: see :mod:`tools.tradeoff.cli`."""

import sys

from tools.tradeoff.cli import main

sys.exit(main())

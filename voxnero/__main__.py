"""``python -m voxnero`` is the same as the ``voxnero`` command."""

import sys

from voxnero.cli import main

sys.exit(main())

"""``python -m hapid``: the same command as ``hapid``."""

import sys

from hapid.cli import main

sys.exit(main())

"""``python -m compd.cli``: the command without the console script (e.g. under systemd)."""

import sys

from compd.cli import main

sys.exit(main())

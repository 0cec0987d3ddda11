"""``python -m artrecon reconstruct DIR_A DIR_B --out DIR`` (same as the ``artrecon`` command)."""

import sys

from artrecon.cli import main

sys.exit(main())

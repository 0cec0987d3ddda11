"""``python -m sim.capture``: see :mod:`sim.capture.cli`."""

from sim.capture.cli import main

raise SystemExit(main())

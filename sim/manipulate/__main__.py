import sys

from sim.manipulate.cli import main

sys.exit(main())

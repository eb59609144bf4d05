import sys

from mks_sim.cli import main

sys.exit(main())

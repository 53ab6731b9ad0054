"""``python -m deck_sim.cli``: the same as the ``deck-sim`` command."""

import sys

from deck_sim.cli import main

sys.exit(main())

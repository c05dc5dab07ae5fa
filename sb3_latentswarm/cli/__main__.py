"""``python -m sb3_latentswarm.cli``: the ``sb3-latentswarm`` command (what ``train --seeds`` runs per seed)."""

import sys

from sb3_latentswarm.cli import main

sys.exit(main())

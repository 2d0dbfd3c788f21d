"""``python -m rig.cli``: the ``ctr-bench`` command without its console script."""
import sys

from rig.cli import main

sys.exit(main())

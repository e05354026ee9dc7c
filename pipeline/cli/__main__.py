"""``python -m treesim.cli``: the ``treesim`` command."""

import sys

from . import main

sys.exit(main())

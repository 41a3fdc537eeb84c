"""``python -m tcd``: the ``tcd`` command line."""

import sys

from ._cli import main

sys.exit(main())

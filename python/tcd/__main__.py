"""``python -m tcd``: the ``tcd`` command line."""

import sys

from .cli import main

sys.exit(main())

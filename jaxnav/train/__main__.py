"""``python -m jaxnav.train``: the command line (``jaxnav.cli``) over this package."""

import sys

from jaxnav.cli import train_main

sys.exit(train_main())

"""``python -m jaxnav.evaluate``: the command line (``jaxnav.cli``) over this package."""

import sys

from jaxnav.cli import evaluate_main

sys.exit(evaluate_main())

"""``python -m jaxcal.cli``."""

import sys

from jaxcal.cli import main

sys.exit(main())

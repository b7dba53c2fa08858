"""``python -m accelcal`` = the ``accelcal`` command."""
import sys

from .cli import main

sys.exit(main())

"""``python -m lpvpc.cli ...``: the ``lpvpc`` command line run as a module."""

import sys

from . import main

sys.exit(main())

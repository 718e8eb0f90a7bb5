"""``python -m synthpack``: the same command line as the ``synthpack`` script."""

import sys

from .cli import main

sys.exit(main())

"""``python -m lbshape.cli``: the ``lbshape`` console script."""

import sys

from lbshape.cli.main import main

sys.exit(main())

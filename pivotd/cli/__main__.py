"""``python -m pivotd.cli``: the ``pivotd`` command."""

import sys

from pivotd.cli import main

sys.exit(main())

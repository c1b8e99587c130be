"""``python -m prismstereo.cli``: the ``prismstereo`` command."""

import sys

from prismstereo.cli import main

sys.exit(main())

"""``python -m rfhoming`` is the ``rfhoming`` command."""

import sys

from rfhoming.cli.main import main

sys.exit(main())

"""``python -m rfhoming`` is the ``rfhoming`` command."""

from rfhoming.cli.main import entry

entry()

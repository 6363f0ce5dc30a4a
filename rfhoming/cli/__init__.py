"""The ``rfhoming`` command line: one module per group of subcommands (see :mod:`.main`)."""

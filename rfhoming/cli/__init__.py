"""The ``rfhoming`` command line: light parsers (:mod:`.parsers`), one module per command
(:mod:`.commands`), dispatched by :mod:`.main`."""

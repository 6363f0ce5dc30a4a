"""One module per command, imported only when that command runs; they never import each other
(an import-linter contract in pyproject.toml): what they share is in rfhoming.cli (live,
printer, signals, site_sources) or the host."""

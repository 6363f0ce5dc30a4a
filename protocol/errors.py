"""The one root of rfhoming's user-facing errors.

Every error a user can cause and fix -- a port spec, a port, a config, a site, a capture, a
scenario -- is an :class:`Error`; its message is one line that names the thing and says how to
fix it. The command line turns an ``Error`` into that line and exit status 2; anything else
that escapes is a bug (exit 1). It lives in the lowest layer so that every layer can raise it.
Subclasses that were ``ValueError`` before stay ``ValueError`` too, for programs that catch it.
"""

from __future__ import annotations


class Error(Exception):
    """A problem the user can fix; ``str(error)`` is one line saying what and how."""

"""A broker login's password: where it may come from, and keeping it out of every text.

The password of the site bus's broker (docs/usage.md section 5c) comes from a file
(``--password-file``) or :data:`PASSWORD_ENV`, not the command line, which every user of the
machine can read (``ps``). Every message, log line and error that may hold a URL goes through
:func:`redact` first, for a password given in a URL all the same. A password written raw in a
URL (``@ : / #`` unencoded, which the URL parser then misreads) is hidden too: its userinfo runs
to the last ``@`` of the word, as it does for the URL parser.
"""

from __future__ import annotations

import re

PASSWORD_ENV = "RFHOMING_MQTT_PASSWORD"
"""The environment variable a broker login's password may come from."""

_USERINFO = re.compile(r"(?P<head>\b[A-Za-z][A-Za-z0-9+.-]*://[^\s:/@'\"]*:)\S*@")
"""``SCHEME://USER:`` then everything of the word up to its last ``@``: the password."""

HIDDEN = "***"


def redact(text: str) -> str:
    """``text`` with the password of every ``SCHEME://USER:PASSWORD@`` in it replaced by ``***``."""
    return _USERINFO.sub(lambda m: f"{m['head']}{HIDDEN}@", text)

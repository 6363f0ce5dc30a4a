"""The key on foxglove-sdk's listener (host/loopback_key.py): on every descriptor of it or on
none; an early connection counted only if it is this process's; the view's warning says why a
listener could not be keyed.

Each test fails on the code before: a key that could be set on one descriptor but not the next
was left on the first (lock() returned None: the front, given no key, could not reach its own
SDK); a connection of another process that shares the port (SO_REUSEADDR) was taken for an
early one and the view refused to start; the view said "no TCP-MD5" whatever the cause."""

from __future__ import annotations

import errno
import logging
import os
import socket
import subprocess
import sys

import pytest
import rigs
from test_client_bounds import SAFETY_S, needs_md5

from rfhoming.host import loopback_key


@needs_md5
def test_a_key_that_one_descriptor_refuses_is_set_on_none(monkeypatch: pytest.MonkeyPatch) -> None:
    with socket.socket() as listener:
        listener.bind(("127.0.0.1", 0))
        listener.listen()
        twin = os.dup(listener.fileno())  # a second descriptor of the listener
        real = socket.socket.setsockopt
        keyed = []

        def second_refuses(sock: socket.socket, level: int, option: int, value: object, *rest: object) -> None:
            if option == loopback_key.TCP_MD5SIG_EXT and isinstance(value, bytes) and any(value[-80:]):
                keyed.append(option)
                if len(keyed) == 2:
                    raise OSError(errno.EINVAL, os.strerror(errno.EINVAL))
            real(sock, level, option, value, *rest)

        monkeypatch.setattr(socket.socket, "setsockopt", second_refuses)
        try:
            with pytest.raises(loopback_key.NotLocked, match="the kernel refused a TCP-MD5 key"):
                loopback_key.lock(listener.getsockname()[1])
        finally:
            os.close(twin)
        monkeypatch.undo()
        plain = socket.create_connection(listener.getsockname(), timeout=SAFETY_S)  # the listener is as it was
        listener.settimeout(SAFETY_S)
        accepted, _ = listener.accept()
        accepted.close()
        plain.close()


CONNECTED_ELSEWHERE = """
import socket, sys
listener = socket.socket()
listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as Rust's TcpListener does
listener.bind(("127.0.0.1", 0))
listener.listen()
print(listener.getsockname()[1], flush=True)
accepted, _ = listener.accept()
listener.close()
print("accepted", flush=True)
sys.stdin.read()  # keeps the connection until the test is done
"""


@needs_md5
def test_another_processs_connection_on_the_same_port_is_no_early_connection() -> None:
    """A listener bound with SO_REUSEADDR (the SDK's, on port 0) may share its port with an
    older connection of another process: that one never reached this listener."""
    other = subprocess.Popen([sys.executable, "-c", CONNECTED_ELSEWHERE], stdin=subprocess.PIPE,
                             stdout=subprocess.PIPE, text=True)
    try:
        port = int(rigs.readline(other))
        with socket.create_connection(("127.0.0.1", port), timeout=SAFETY_S):
            assert rigs.readline(other) == "accepted\n"
            with socket.socket() as listener:
                listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                listener.bind(("127.0.0.1", port))
                listener.listen()
                assert loopback_key.connections_to(port) == 0
                assert loopback_key.lock(port)
    finally:
        other.stdin.close()
        other.wait(SAFETY_S)
        other.stdout.close()


@pytest.mark.parametrize(("cause", "said"), [
    (OSError(errno.EACCES, os.strerror(errno.EACCES)), "/proc/self/fd cannot be read (Permission denied)"),
    (None, "no listening socket of this process is at that address"),
])
def test_the_views_warning_says_why_the_listener_is_not_locked(monkeypatch: pytest.MonkeyPatch,
                                                                caplog: pytest.LogCaptureFixture,
                                                                cause: OSError | None, said: str) -> None:
    pytest.importorskip("foxglove")
    from rfhoming.host.foxglove_view import FoxgloveView

    def listening(port: int) -> list[int]:
        if cause is not None:
            raise cause
        return []

    monkeypatch.setattr(loopback_key, "_listening", listening)
    caplog.set_level(logging.WARNING)
    view = FoxgloveView(port=0)
    view.close()
    warned = [r.getMessage() for r in caplog.records if "cannot be locked" in r.getMessage()]
    assert len(warned) == 1 and said in warned[0] and "TCP-MD5" not in warned[0], warned

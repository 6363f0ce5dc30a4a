"""How many clients one source may keep idle on a server (``serve``, the Foxglove front).

A client is *idle* from the moment it connects until it first asks for something (a command
to ``serve``, any message after the WebSocket handshake to the Foxglove front). An idle
client costs a slot and sends nothing, so a program that opens connections and forgets them
(or means to fill the server) could hold every slot. At most ``per_source`` clients from one
address are idle at once: when another arrives, the one idle longest is let go, so a new
client always gets in and a client that has spoken is never let go for this. Clients on the
same machine share one address (127.0.0.1): they share the bound too.
"""

from __future__ import annotations

from typing import Generic, TypeVar

Client = TypeVar("Client")


class IdleClients(Generic[Client]):
    """The idle clients of each source, oldest first."""

    def __init__(self, per_source: int) -> None:
        if per_source < 1:
            raise ValueError(f"per_source is at least 1, not {per_source}")
        self.per_source = per_source
        self._idle: dict[str, dict[Client, None]] = {}  # source -> its idle clients, in arrival order
        self._source: dict[Client, str] = {}

    def arrived(self, source: str, client: Client) -> Client | None:
        """Count a new client as idle; the client of ``source`` idle longest, to be let go, when
        the source has more than ``per_source`` idle (else None)."""
        idle = self._idle.setdefault(source, {})
        idle[client] = None
        self._source[client] = source
        if len(idle) <= self.per_source:
            return None
        oldest = next(iter(idle))
        self.left(oldest)
        return oldest

    def spoke(self, client: Client) -> None:
        """The client asked for something: it is idle no more."""
        self.left(client)

    def left(self, client: Client) -> None:
        """The client is gone (or spoke): forget it."""
        source = self._source.pop(client, None)
        if source is None:
            return
        idle = self._idle[source]
        idle.pop(client, None)
        if not idle:
            del self._idle[source]

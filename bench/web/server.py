"""The web station's HTTP server: uvicorn with every wait bounded, and no proxy header believed
unless the station is told which proxies to believe.

* **Requests that never finish** (a client that sends half a request and waits, one byte every few
  seconds: "slowloris") are closed: the request line and headers must arrive within
  :data:`HEADER_TIMEOUT_S` of the connection (or of the previous response), the body within
  :data:`BODY_TIMEOUT_S` of the headers; then ``408 Request Timeout`` and the connection is closed.
  uvicorn has a keep-alive timeout for idle connections between requests, but no limit on reading
  one: before, 20 of 20 incomplete requests were still open after 65 s (:class:`TimedH11Protocol`).
* **Proxy headers** (``X-Forwarded-For``, ``X-Forwarded-Proto``): uvicorn believes them by default
  from 127.0.0.1, so any local process could set the origin recorded with an answer or a stop.
  They are ignored unless ``bench serve --trusted-proxy ADDRESS`` names the proxies (then only
  from those).

The body size and the ``Host`` header are checked by :mod:`bench.web.guards`.
"""

from __future__ import annotations

import asyncio
from typing import Any, Sequence

import h11
from uvicorn.protocols.http.h11_impl import H11Protocol

HEADER_TIMEOUT_S = 10.0
"""Longest time (s) for a request's line and headers to arrive, from the connection or the previous response."""
BODY_TIMEOUT_S = 10.0
"""Longest time (s) for a request's body (64 KiB at most) to arrive once its headers have."""
KEEP_ALIVE_S = 5
"""Longest idle time (s) of a connection between requests (uvicorn's ``timeout_keep_alive``)."""
SHUTDOWN_GRACE_S = 5
"""Longest wait (s) for open requests when the server stops."""

_TIMEOUT_RESPONSE = (b"HTTP/1.1 408 Request Timeout\r\ncontent-type: application/json\r\nconnection: close\r\n"
                     b"content-length: %d\r\n\r\n%s")


class TimedH11Protocol(H11Protocol):
    """uvicorn's h11 protocol with a deadline on reading each request (see the module docstring)."""

    header_timeout_s = HEADER_TIMEOUT_S
    body_timeout_s = BODY_TIMEOUT_S

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        self._read_timer: asyncio.TimerHandle | None = None
        self._phase = ""
        super().connection_made(transport)
        self._follow()

    def connection_lost(self, exc: Exception | None) -> None:
        self._disarm()
        super().connection_lost(exc)

    def handle_events(self) -> None:
        super().handle_events()
        self._follow()

    def _follow(self) -> None:
        """Arm, move or stop the deadline after the request's state changed."""
        state = self.conn.their_state
        if state is h11.IDLE:
            phase, seconds = "head", self.header_timeout_s
        elif state is h11.SEND_BODY:
            phase, seconds = "body", self.body_timeout_s
        else:  # DONE (the whole request is here), MUST_CLOSE, CLOSED, ERROR
            self._phase = "done"
            self._disarm()
            return
        if phase != self._phase:
            self._phase = phase
            self._disarm()
            self._read_timer = self.loop.call_later(seconds, self._timed_out)

    def _disarm(self) -> None:
        if getattr(self, "_read_timer", None) is not None:
            self._read_timer.cancel()  # type: ignore[union-attr]
            self._read_timer = None

    def _timed_out(self) -> None:
        self._read_timer = None
        if self.transport.is_closing():
            return
        cycle = self.cycle
        if cycle is None or not cycle.response_started:
            what = "headers" if self._phase == "head" else "body"
            seconds = self.header_timeout_s if self._phase == "head" else self.body_timeout_s
            msg = b'{"errors": ["the request %s did not arrive within %g s"]}' % (what.encode(), seconds)
            self.transport.write(_TIMEOUT_RESPONSE % (len(msg), msg))
        if cycle is not None:
            cycle.disconnected = True  # the application's receive() ends, its send() is dropped
            cycle.message_event.set()
        self.transport.close()


def server_config(app: Any, *, trusted_proxies: Sequence[str] = (), request_timeout_s: float = HEADER_TIMEOUT_S) -> Any:
    """The ``uvicorn.Config`` of the station's app: :class:`TimedH11Protocol` (headers within
    ``request_timeout_s``, the body within as long again), keep-alive :data:`KEEP_ALIVE_S`, no
    websockets, proxy headers only from ``trusted_proxies``."""
    import uvicorn

    protocol = type("TimedH11Protocol", (TimedH11Protocol,), {"header_timeout_s": request_timeout_s, "body_timeout_s": request_timeout_s})
    return uvicorn.Config(app, http=protocol, ws="none", log_level="warning", access_log=False, lifespan="on",
                          timeout_keep_alive=KEEP_ALIVE_S, timeout_graceful_shutdown=SHUTDOWN_GRACE_S,
                          proxy_headers=bool(trusted_proxies), forwarded_allow_ips=list(trusted_proxies) or None)

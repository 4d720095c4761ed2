"""Checks made on every request before any endpoint runs: the ``Host`` it names and the size of
its body.

**Host.** A page on ``attacker.example`` whose name the attacker then points at 127.0.0.1 (DNS
rebinding) makes the browser send requests to the station with ``Host: attacker.example``, and
read the answers: runs, files, reports. The station answers only requests naming one of its own
names (:func:`allowed_hosts`): the address it listens on, ``localhost`` and the loopback addresses,
and the names given with ``bench serve --allow-host NAME``. A station listening on every address
(``--host 0.0.0.0``) also answers any IP address (a rebinding needs a name; an address cannot be
re-pointed). Other names get 421 and nothing else. A request without ``Host`` (HTTP/1.0) names
nothing that could have been rebound and is served.

**Body size.** A ``Content-Length`` above :data:`bench.web.requests.MAX_BODY_BYTES` is refused with
413 before a byte of the body is read (before, 200 MB were read first, and the server grew from 231
to 622 MB); a body without a length is counted as it arrives (:func:`read_body`).
"""

from __future__ import annotations

import ipaddress
import json
from typing import Any, Awaitable, Callable, Iterable

from bench.terminal_text import printable
from bench.web.requests import MAX_BODY_BYTES, BodyTooLarge

WILDCARDS = ("0.0.0.0", "::", "")
LOOPBACK_NAMES = ("localhost", "127.0.0.1", "::1")

Scope = dict[str, Any]
Receive = Callable[[], Awaitable[dict[str, Any]]]
Send = Callable[[dict[str, Any]], Awaitable[None]]


def allowed_hosts(bind_host: str, extra: Iterable[str] = ()) -> frozenset[str]:
    """The names a request's ``Host`` may give: ``bind_host`` (unless a wildcard), ``localhost``,
    the loopback addresses and ``extra``, lower case, without brackets or a trailing dot."""
    names = {*LOOPBACK_NAMES, *(h for h in (bind_host,) if h not in WILDCARDS), *extra}
    return frozenset(_norm(n) for n in names if n)


def _norm(name: str) -> str:
    return name.strip().strip("[]").rstrip(".").lower()


def host_of(value: str) -> str:
    """The host part of a ``Host`` header value (``name``, ``name:port``, ``[v6]:port``), normalised."""
    v = value.strip()
    if v.startswith("["):
        return _norm(v[1:v.find("]")] if "]" in v else v)
    if v.count(":") == 1:
        v = v.split(":", 1)[0]
    return _norm(v)


def _is_ip(name: str) -> bool:
    try:
        ipaddress.ip_address(name)
        return True
    except ValueError:
        return False


class RequestGuard:
    """ASGI middleware: refuses a foreign ``Host`` (421) and a declared body larger than
    :data:`MAX_BODY_BYTES` (413) before the application sees the request."""

    def __init__(self, app: Any, allowed: frozenset[str], any_ip: bool = False):
        self.app = app
        self.allowed = allowed
        self.any_ip = any_ip

    def allows(self, host_header: str) -> bool:
        name = host_of(host_header)
        return name in self.allowed or (self.any_ip and _is_ip(name))

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = {k.lower(): v for k, v in scope.get("headers", [])}
        host = headers.get(b"host")
        if host is not None and not self.allows(host.decode("latin-1")):
            shown = printable(host.decode("latin-1"))[:100]
            await _refuse(send, 421, f"this station does not answer to the name {shown!r} (a page of another site reaching it "
                                     f"through a re-pointed name); it answers to {', '.join(sorted(self.allowed))}: start it with "
                                     "--allow-host NAME to add a name")
            return
        length = headers.get(b"content-length")
        if length is not None:
            try:
                n = int(length)
            except ValueError:
                n = -1
            if n < 0 or n > MAX_BODY_BYTES:
                await _refuse(send, 413 if n > MAX_BODY_BYTES else 400,
                              f"request body larger than {MAX_BODY_BYTES} bytes" if n > MAX_BODY_BYTES else "bad Content-Length")
                return
        await self.app(scope, receive, send)


async def _refuse(send: Send, status: int, message: str) -> None:
    body = json.dumps({"errors": [message]}).encode()
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()),
                            (b"connection", b"close")]})
    await send({"type": "http.response.body", "body": body})


async def read_body(request: Any) -> bytes:
    """The body of a Starlette ``request``, at most :data:`MAX_BODY_BYTES`: :class:`BodyTooLarge`
    as soon as more arrives (a body sent without a length, chunked)."""
    chunks: list[bytes] = []
    size = 0
    async for chunk in request.stream():
        size += len(chunk)
        if size > MAX_BODY_BYTES:
            raise BodyTooLarge()
        chunks.append(chunk)
    return b"".join(chunks)

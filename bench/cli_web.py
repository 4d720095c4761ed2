"""``bench serve``: the web station (docs/web.md)."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from bench.cli_common import epilog, quantity
from bench.errors import EXIT_OK, InputError

if TYPE_CHECKING:  # pragma: no cover
    from rich.console import Console

TOKEN_ENV = "BENCH_WEB_TOKEN"
"""Environment variable with the control token (instead of ``--token``, which other users see in ``ps``)."""
MIN_TOKEN_CHARS = 12


def add_serve_parser(sub: argparse._SubParsersAction) -> None:
    """The ``serve`` command's parser."""
    sv = sub.add_parser(
        "serve", help="web station: runs, run pages with plots, live runs started, answered and stopped from a browser",
        description="Serve the web station on one port: the catalogue of runs with filters, each run's page (verdict, checks, "
                    "steps, every stream plotted, events, report and file), live runs (current step, interlocks, prompts "
                    "answered from the page, pause and stop) and runs started from the procedure library. Reading is open; "
                    "starting, answering, pausing and stopping need the token printed at start-up (docs/web.md).",
        epilog=epilog("bench serve", "bench serve --config configs/lab.yaml --runs-dir /data/runs",
                      "BENCH_WEB_TOKEN=... bench serve --host 0.0.0.0 --port 8080",
                      ok="the server was stopped (Ctrl-C, SIGTERM) after stopping the runs it started",
                      bad="bad option or config, or the port is taken (one line)"))
    sv.add_argument("--runs-dir", type=Path, default=Path("runs"), help="run files and, by default, their catalogue (default: runs/)")
    sv.add_argument("--config", type=Path, default=None,
                    help="lab config: real runs on its instruments, dry-runs on its simulators (default: dry-runs only, "
                         "on configs/sim.yaml next to the procedure library)")
    sv.add_argument("--procedures", type=Path, default=Path("procedures"), help="procedure library to start runs from (default: procedures/)")
    sv.add_argument("--catalog", metavar="URL", default=None, help="catalogue of runs (default: the config's 'catalog:', else RUNS_DIR/catalog.sqlite)")
    sv.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1: this computer only)")
    sv.add_argument("--port", type=int, default=8765, help="TCP port (default 8765; 0: any free port, printed)")
    sv.add_argument("--token", default=None, help=f"control token (default: ${TOKEN_ENV}, else a new random one, printed)")
    sv.add_argument("--allow-host", action="append", default=[], metavar="NAME",
                    help="another name the station answers to in the Host header (repeatable; default: the --host address, "
                         "localhost and the loopback addresses; a name other computers reach it by, e.g. bench-station.lab)")
    sv.add_argument("--request-timeout", default="10 s", metavar="DURATION",
                    help="longest time for a request's headers to arrive, and as long again for its body; an incomplete "
                         "request is then answered 408 and closed (default 10 s)")
    sv.add_argument("--trusted-proxy", action="append", default=[], metavar="ADDRESS",
                    help="a reverse proxy in front of the station whose X-Forwarded-For is believed for the origin recorded "
                         "with controls (repeatable; default: none, the origin is the connection's address)")


def _bind(host: str, port: int):
    """A listening socket on ``host:port`` (:class:`InputError` naming ``--port``/``--host`` when refused)."""
    import errno
    import socket

    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except socket.gaierror as exc:
        raise InputError(f"cannot listen on {host!r}: {exc.strerror}", None, "--host") from None
    family, _, _, _, address = infos[0]
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind(address)
        sock.listen(128)
    except OSError as exc:
        sock.close()
        why = "is in use (another 'bench serve'?)" if exc.errno == errno.EADDRINUSE else f"cannot be bound: {exc.strerror}"
        raise InputError(f"port {port} on {host} {why}", None, "--port") from None
    return sock


def _host_name(value: str, option: str) -> str:
    """A name for ``--allow-host``: a DNS name or an address, without a port or a scheme."""
    import ipaddress
    import re

    v = value.strip().strip("[]").rstrip(".").lower()
    try:
        ipaddress.ip_address(v)
        return v
    except ValueError:
        pass
    if not re.fullmatch(r"[a-z0-9](?:[a-z0-9-]{0,61}[a-z0-9])?(?:\.[a-z0-9](?:[a-z0-9-]{0,61}[a-z0-9])?)*", v) or len(v) > 253:
        raise InputError(f"expected a host name such as bench-station.lab or an address, got {value!r}", None, option)
    return v


def _proxy_address(value: str) -> str:
    """An address or network for ``--trusted-proxy`` (``10.0.0.5``, ``10.0.0.0/24``)."""
    import ipaddress

    try:
        return str(ipaddress.ip_network(value.strip(), strict=False) if "/" in value else ipaddress.ip_address(value.strip()))
    except ValueError:
        raise InputError(f"expected an IP address or network such as 10.0.0.5 or 10.0.0.0/24, got {value!r}", None,
                         "--trusted-proxy") from None


def cmd_serve(args: argparse.Namespace, console: Console) -> int:
    if not 0 <= args.port <= 65535:
        raise InputError(f"expected a TCP port 0..65535, got {args.port}", None, "--port")
    allow_hosts = tuple(_host_name(h, "--allow-host") for h in args.allow_host)
    request_timeout_s = quantity(args.request_timeout, "s", "--request-timeout")
    if not 0.1 <= request_timeout_s <= 600:
        raise InputError(f"expected 0.1 s to 600 s, got {args.request_timeout!r}", None, "--request-timeout")
    trusted = tuple(_proxy_address(a) for a in args.trusted_proxy)
    token = args.token if args.token is not None else os.environ.get(TOKEN_ENV) or None
    if token is not None and (len(token) < MIN_TOKEN_CHARS or not token.isprintable() or " " in token):
        raise InputError(f"the token must be at least {MIN_TOKEN_CHARS} printable characters without spaces", None,
                         "--token" if args.token is not None else TOKEN_ENV)
    import secrets

    token = token or secrets.token_urlsafe(18)
    if args.runs_dir.exists() and not args.runs_dir.is_dir():
        raise InputError(f"{args.runs_dir}: not a directory", None, "--runs-dir")
    catalog = args.catalog
    operators: tuple[str, ...] = ()
    if args.config is not None:
        from bench.cli_catalog import run_catalog
        from bench.config import load_config

        lab = load_config(args.config)
        catalog, operators = run_catalog(args.catalog, lab), lab.operators
    elif catalog:
        from bench.catalog.store import resolve_url

        resolve_url(catalog, field="--catalog")
    sim_config = args.procedures.parent / "configs" / "sim.yaml"
    try:
        args.runs_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{args.runs_dir}: cannot create it: {exc.strerror}", None, "--runs-dir") from None
    sock = _bind(args.host, args.port)

    import uvicorn

    from bench.web.app import Station, create_app
    from bench.web.server import server_config

    station = Station(runs_dir=args.runs_dir.resolve(), library=args.procedures.resolve(), token=token,
                      config=args.config.resolve() if args.config else None,
                      sim_config=sim_config.resolve() if sim_config.is_file() else None, catalog=catalog, operators=operators)
    host, port = sock.getsockname()[:2]
    shown = f"[{host}]" if ":" in host else host
    print(f"bench serve: http://{shown}:{port}/", flush=True)
    print(f"token (for starting, answering, pausing and stopping runs): {token}", flush=True)
    if not station.library.is_dir():
        print(f"bench: warning: no procedure library at {args.procedures}: runs cannot be started from the page", file=sys.stderr, flush=True)
    if args.host not in ("127.0.0.1", "localhost", "::1"):
        print(f"bench: warning: listening on {args.host}: other computers can read the runs (controls need the token); "
              f"it answers to its addresses, localhost{''.join(', ' + h for h in allow_hosts)} (--allow-host NAME adds a name)",
              file=sys.stderr, flush=True)
    app = create_app(station, bind_host=host, allow_hosts=(args.host, *allow_hosts))
    server = uvicorn.Server(server_config(app, trusted_proxies=trusted, request_timeout_s=request_timeout_s))
    server.run(sockets=[sock])
    return EXIT_OK

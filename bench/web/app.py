"""The web station's HTTP application (Starlette): pages, JSON API, access rules.

Reading is open (runs table, run pages, plots, report, file download); every control (start,
answer, pause/resume, stop) needs ``Authorization: Bearer <token>``: without it the answer is 401,
with a wrong one 403, and nothing happens. Controls reach a run only through the runner's
thread-safe flags and its queue of operator events; each is recorded in the run file with its
origin (``web <client address>``). Request values are never executed and never used as paths
except through :mod:`bench.web.paths`. Endpoints: docs/web.md.
"""

from __future__ import annotations

import contextlib
import hmac
import json
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, AsyncIterator, Callable

from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.requests import Request
from starlette.responses import FileResponse, HTMLResponse, JSONResponse, Response
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles

from bench.errors import InputError, InputErrors, finite_number
from bench.web.decimate import StreamCache, decimate, xy_pairs
from bench.web.live import LiveRuns
from bench.web.pages import LiveReader, run_page, runs_table
from bench.web.paths import run_path

STATIC = Path(__file__).parent / "static"
MAX_BODY_BYTES = 64 * 1024
"""Largest request body accepted (bytes)."""
SECURITY_HEADERS = {
    "Content-Security-Policy": "default-src 'self'; img-src 'self' data:; style-src 'self'; script-src 'self'; frame-ancestors 'none'",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
}


@dataclass
class Station:
    """What the server serves: ``runs_dir`` (run files and, by default, the catalogue), ``library``
    (procedure files), ``config`` (the lab, for real runs and its simulators), ``sim_config`` (the
    simulated lab of dry-runs without ``config``), the control ``token``."""

    runs_dir: Path
    library: Path
    token: str
    config: Path | None = None
    sim_config: Path | None = None
    catalog: str | None = None
    operators: tuple[str, ...] = ()
    """The lab config's ``operators:`` (empty: any name)."""
    runs: LiveRuns = field(default_factory=LiveRuns)
    cache: StreamCache = field(default_factory=StreamCache)
    live: LiveReader = field(default_factory=LiveReader)
    _reports: dict[tuple, str] = field(default_factory=dict)
    _report_lock: threading.Lock = field(default_factory=threading.Lock)

    def report(self, path: Path) -> str:
        """The HTML report of ``path`` (``bench report``), kept while the file does not change."""
        from bench.report.run_report import build_report

        st = path.stat()
        key = (str(path), st.st_mtime_ns, st.st_size)
        with self._report_lock:
            if key in self._reports:
                return self._reports[key]
        html = build_report(path)
        with self._report_lock:
            self._reports = {k: v for k, v in self._reports.items() if k[0] != str(path)}
            self._reports[key] = html
        return html


def _json(data: Any, status: int = 200) -> JSONResponse:
    return JSONResponse(data, status_code=status, headers=SECURITY_HEADERS)


def _errors(exc: InputError | InputErrors, status: int = 400) -> JSONResponse:
    lines = [e.one_line() for e in exc.errors] if isinstance(exc, InputErrors) else [exc.one_line()]
    return _json({"errors": lines}, status)


def _float(request: Request, name: str) -> float | None:
    text = request.query_params.get(name, "")
    if text in ("", "null", "undefined"):
        return None
    return finite_number(text, None, name)


def _int(request: Request, name: str, default: int) -> int:
    text = request.query_params.get(name, "")
    try:
        return int(text) if text else default
    except ValueError:
        raise InputError(f"expected an integer, got {text!r}", None, name) from None


def origin(request: Request) -> str:
    """``web <client address>``: the origin recorded with each control action."""
    from bench.operators import web_origin

    return web_origin(request.client.host if request.client else "")


def acting_person(station: "Station", body: dict, required: bool) -> str:
    """The name of the person acting from the page (the body's ``operator``): checked as a run's
    operator is, against the lab's list when it has one; ``""`` when not given and not ``required``
    (a stop is never refused for want of a name)."""
    from bench import operators

    name = body.get("operator")
    if (name is None or (isinstance(name, str) and not name.strip())) and not required:
        return ""
    return operators.resolve(name if isinstance(name, str) else str(name), station.operators, origin="", field="operator",
                             required=True).name


def unit_of(station: Station, request: Request) -> Any:
    """The :class:`~bench.unit_history.UnitHistory` of the request's ``serial`` (and ``part``)."""
    from bench.unit_history import unit_history
    from bench.web.pages import add_uncatalogued

    q = request.query_params
    return unit_history(q.get("serial", ""), runs_dir=station.runs_dir, catalog=station.catalog, part=q.get("part") or None,
                        prepare=lambda cat: add_uncatalogued(cat, station.runs_dir), field="serial")


def create_app(station: Station) -> Starlette:
    """The application serving ``station``."""

    def guarded(fn: Callable[..., Response]) -> Callable:
        """A read endpoint: bad input is 400 with located lines, an unknown run 404."""
        async def endpoint(request: Request) -> Response:
            try:
                return await run_in_threadpool(fn, request)
            except (InputError, InputErrors) as exc:
                missing = isinstance(exc, InputError) and exc.message.startswith(("no run id", "no catalogued run"))
                return _errors(exc, 404 if missing else 400)
        return endpoint

    def control(fn: Callable[[Request, dict], Response]) -> Callable:
        """A control endpoint: the token first (401 without, 403 wrong), then the JSON body."""
        async def endpoint(request: Request) -> Response:
            auth = request.headers.get("authorization", "")
            if not auth.lower().startswith("bearer ") or not auth[7:].strip():
                return _json({"errors": ["this action needs the station's token: Authorization: Bearer <token>"]}, 401)
            if not hmac.compare_digest(auth[7:].strip().encode(), station.token.encode()):
                return _json({"errors": ["wrong token"]}, 403)
            raw = await request.body()
            if len(raw) > MAX_BODY_BYTES:
                return _json({"errors": [f"request body larger than {MAX_BODY_BYTES} bytes"]}, 413)
            try:
                body = json.loads(raw or b"{}")
            except (ValueError, UnicodeDecodeError):
                return _json({"errors": ["expected a JSON object"]}, 400)
            if not isinstance(body, dict):
                return _json({"errors": ["expected a JSON object"]}, 400)
            try:
                return await run_in_threadpool(fn, request, body)
            except (InputError, InputErrors) as exc:
                return _errors(exc)
        return endpoint

    def page(_request: Request) -> Response:
        return FileResponse(STATIC / "index.html", headers=SECURITY_HEADERS)

    def path_of(request: Request) -> Path:
        return run_path(station.runs_dir, request.query_params.get("id", ""))

    def api_session(_request: Request) -> Response:
        from bench.web.launch import lab_description

        return _json({"runs_dir": str(station.runs_dir), "config": str(station.config) if station.config else None,
                      "dry_run_config": str(station.config or station.sim_config or "") or None,
                      "real_lab": station.config is not None, "library": str(station.library), "operators": list(station.operators),
                      "lab": lab_description(station.config, station.sim_config)})

    def api_runs(request: Request) -> Response:
        table = runs_table(station.runs_dir, station.catalog, dict(request.query_params))
        for r in table["runs"]:
            r["in_process"] = bool(r["id"]) and station.runs.get(r["id"]) is not None
        return _json(table)

    def api_run(request: Request) -> Response:
        path = path_of(request)
        data = run_page(path)
        data["id"] = request.query_params["id"]
        live = station.runs.get(data["id"])
        data["control"] = live.state() if live is not None else None
        return _json(data)

    def api_live(request: Request) -> Response:
        rid = request.query_params.get("id", "")
        path = path_of(request)
        live = station.runs.get(rid)
        try:
            snap = station.live.snapshot(path)
            error = ""
        except InputError as exc:
            snap, error = None, exc.one_line()
        return _json({"id": rid, "file": snap, "error": error, "control": live.state() if live is not None else None})

    def api_stream(request: Request) -> Response:
        path = path_of(request)
        return _json(decimate(path, request.query_params.get("key", ""), request.query_params.get("column", ""),
                              t0=_float(request, "t0"), t1=_float(request, "t1"), px=_int(request, "px", 1200), cache=station.cache))

    def api_xy(request: Request) -> Response:
        path = path_of(request)
        q = request.query_params
        x = (q.get("xkey", ""), q.get("xcol", ""), _int(request, "xi", 0))
        y = (q.get("ykey", ""), q.get("ycol", ""), _int(request, "yi", 0))
        return _json(xy_pairs(path, x, y, t0=_float(request, "t0"), t1=_float(request, "t1"), points=_int(request, "points", 1000),
                              cache=station.cache))

    def api_report(request: Request) -> Response:
        return HTMLResponse(station.report(path_of(request)))

    def api_unit(request: Request) -> Response:
        from bench.unit_history import history_json

        return _json(history_json(unit_of(station, request)))

    def api_unit_package(request: Request) -> Response:
        from bench.report.unit_package import build_package

        h = unit_of(station, request)
        name = "".join(c if c.isalnum() or c in "-_." else "_" for c in h.serial)
        return HTMLResponse(build_package(h), headers={**SECURITY_HEADERS,
                                                       "Content-Disposition": f'attachment; filename="{name}_acceptance.html"'})

    def api_file(request: Request) -> Response:
        path = path_of(request)
        return FileResponse(path, filename=path.name, media_type="application/x-hdf5")

    def api_procedures(_request: Request) -> Response:
        from bench.web.launch import library

        return _json({"procedures": library(station.library)})

    def api_plan(request: Request) -> Response:
        from bench.web.launch import clean_params, plan

        q = request.query_params
        params = clean_params(json.loads(q.get("params") or "{}")) if q.get("params") else {}
        return _json(plan(station.library, q.get("procedure", ""), params, station.config or station.sim_config))

    def api_start(request: Request, body: dict) -> Response:
        from bench.web.launch import StartRequest, clean_params, start

        req = StartRequest(procedure=str(body.get("procedure", "")), params=clean_params(body.get("params")),
                           unit=str(body.get("unit") or "").strip() or None, dry_run=bool(body.get("dry_run", True)),
                           realtime=bool(body.get("realtime", True)), accept_overdue=bool(body.get("accept_overdue", False)),
                           operator=str(body.get("operator") or ""), origin=origin(request))
        live = start(req, library_dir=station.library, config_path=station.config, sim_config=station.sim_config,
                     runs_dir=station.runs_dir, catalog=station.catalog, runs=station.runs, busy=station.runs.busy_instruments())
        return _json({"id": live.run_id, "file": live.path.name})

    def _live_or_error(body: dict) -> Any:
        rid = str(body.get("id", ""))
        run_path(station.runs_dir, rid)
        live = station.runs.get(rid)
        if live is None:
            raise InputError(f"run {rid!r} was not started from this station: its controls are in the terminal that runs it")
        if live.done.is_set():
            raise InputError(f"run {rid!r} has ended")
        return live

    def api_answer(request: Request, body: dict) -> Response:
        from bench.web.live import check_answer

        live = _live_or_error(body)
        text = check_answer(body.get("answer"), body.get("confirm_abort"))
        person = acting_person(station, body, required=True)
        if not live.asker.answer(text, origin(request), person):
            return _json({"errors": ["no question is waiting for an answer"]}, 409)
        return _json({"ok": True})

    def api_pause(request: Request, body: dict) -> Response:
        live = _live_or_error(body)
        person = acting_person(station, body, required=False)
        want = bool(body.get("paused", not live.runner.paused))
        if want != live.runner.paused:
            live.runner.operator_event("pause" if want else "resume", origin(request),
                                       f"{'pause' if want else 'resume'} requested from the web station", operator=person)
            live.runner.toggle_pause()
        return _json({"ok": True, "paused": want})

    def api_stop(request: Request, body: dict) -> Response:
        live = _live_or_error(body)
        person = acting_person(station, body, required=False)
        who = origin(request)
        live.runner.operator_event("stop", who, "stop requested from the web station", operator=person)
        live.runner.request_abort(f"operator stop from the web station ({who})" + (f" by {person}" if person else ""))
        return _json({"ok": True})

    routes = [
        Route("/", page), Route("/run", page), Route("/start", page), Route("/unit", page),
        Route("/api/unit", guarded(api_unit)),
        Route("/api/unit_package", guarded(api_unit_package)),
        Route("/api/session", guarded(api_session)),
        Route("/api/runs", guarded(api_runs)),
        Route("/api/run", guarded(api_run)),
        Route("/api/live", guarded(api_live)),
        Route("/api/stream", guarded(api_stream)),
        Route("/api/xy", guarded(api_xy)),
        Route("/api/report", guarded(api_report)),
        Route("/api/file", guarded(api_file)),
        Route("/api/procedures", guarded(api_procedures)),
        Route("/api/plan", guarded(api_plan)),
        Route("/api/start", control(api_start), methods=["POST"]),
        Route("/api/answer", control(api_answer), methods=["POST"]),
        Route("/api/pause", control(api_pause), methods=["POST"]),
        Route("/api/stop", control(api_stop), methods=["POST"]),
        Mount("/static", StaticFiles(directory=STATIC), name="static"),
    ]

    @contextlib.asynccontextmanager
    async def lifespan(_app: Starlette) -> AsyncIterator[None]:
        yield
        # the server stops (Ctrl-C): runs started here are stopped like a Ctrl-C of 'bench run'
        await run_in_threadpool(station.runs.stop_all, "the web station stopped")

    return Starlette(routes=routes, lifespan=lifespan)

"""The web station's HTTP application (Starlette): pages, JSON API, access rules.

Reading is open (runs table, run pages, plots, report, file download); every control (start,
answer, pause/resume, stop) needs ``Authorization: Bearer <token>``: without it the answer is 401,
with a wrong one 403, and nothing happens. Controls reach a run only through the runner's
thread-safe flags and its queue of operator events; each is recorded in the run file with its
origin (``web <client address>``: the socket's peer, never a proxy header unless the station was
told which proxies to believe, :mod:`bench.web.server`). Request values are typed strictly
(:mod:`bench.web.requests`), never executed and never used as paths except through
:mod:`bench.web.paths`. Endpoints: docs/web.md.

Capacity (issue 31): reads run on at most :data:`READ_THREADS` worker threads and controls on
their own :data:`CONTROL_THREADS`, so no number of slow reads can make a stop wait; a read never
writes the catalogue (:mod:`bench.web.runs_index`). The ``Host`` of every request and the size of
its body are checked first (:mod:`bench.web.guards`). A run file that still holds a credential (one
written before they were masked) is not served; pages and reports show texts with credentials
masked (:mod:`bench.redact`).
"""

from __future__ import annotations

import contextlib
import hmac
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, AsyncIterator, Callable

import anyio
import anyio.to_thread
from starlette.applications import Starlette
from starlette.requests import ClientDisconnect, Request
from starlette.responses import FileResponse, HTMLResponse, JSONResponse, Response
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles

from bench.errors import InputError, InputErrors
from bench.redact import redact, redact_data
from bench.web.credentials import CredentialCheck
from bench.web.decimate import StreamCache, decimate, xy_pairs
from bench.web.guards import read_body
from bench.web.live import LiveRuns
from bench.web.pages import FILTERS, LiveReader, run_page, runs_table
from bench.web.paths import run_path
from bench.web.requests import MAX_BODY_BYTES, BodyTooLarge, Field, parse_body, query
from bench.web.runs_index import RunsIndex

STATIC = Path(__file__).parent / "static"
READ_THREADS = 8
"""Worker threads serving reads (runs, run pages, plots, reports, files, plans) at most at once."""
CONTROL_THREADS = 4
"""Worker threads of the controls (start, answer, pause, stop), which reads cannot take."""
PLAN_CACHE = 64
"""Plans kept (procedure, parameters and config unchanged: the same text)."""
_ID = Field("text", required=True, max_chars=1024)
_OPERATOR = Field("name", nullable=True)
START_FIELDS = {"procedure": Field("text", required=True, max_chars=1024), "params": Field("params", {}),
                "unit": Field("text", None, max_chars=64, nullable=True), "dry_run": Field("bool", True), "realtime": Field("bool", True),
                "accept_overdue": Field("bool", False), "operator": _OPERATOR}
"""The fields of ``POST /api/start`` (every other field is refused)."""
ANSWER_FIELDS = {"id": _ID, "answer": Field("text", required=True), "confirm_abort": Field("bool", False), "operator": _OPERATOR}
"""``POST /api/answer``: a "no" needs ``confirm_abort: true`` (it stops the run; :func:`bench.web.live.check_answer`)."""
PAUSE_FIELDS = {"id": _ID, "paused": Field("bool", None, nullable=True), "operator": _OPERATOR}
STOP_FIELDS = {"id": _ID, "operator": _OPERATOR}
_TIME = {"t0": Field("number", None, lo=-1e12, hi=1e12), "t1": Field("number", None, lo=-1e12, hi=1e12)}
RUN_QUERY = {"id": Field("text", "", max_chars=1024)}
STREAM_QUERY = {**RUN_QUERY, "key": Field("text", "", max_chars=256), "column": Field("text", "", max_chars=256), **_TIME,
                "px": Field("int", 1200, lo=1, hi=20_000)}
XY_QUERY = {**RUN_QUERY, **{k: Field("text", "", max_chars=256) for k in ("xkey", "xcol", "ykey", "ycol")}, **_TIME,
            "xi": Field("int", 0, lo=0, hi=1_000), "yi": Field("int", 0, lo=0, hi=1_000), "points": Field("int", 1000, lo=1, hi=100_000)}
RUNS_QUERY = {k: Field("text", "", max_chars=200) for k in FILTERS}
UNIT_QUERY = {"serial": Field("text", "", max_chars=64), "part": Field("text", "", max_chars=64)}
PLAN_QUERY = {"procedure": Field("text", "", max_chars=1024), "params": Field("json", None, max_chars=8192)}
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
    index: RunsIndex | None = None
    _reports: dict[tuple, str] = field(default_factory=dict)
    _report_lock: threading.Lock = field(default_factory=threading.Lock)
    credentials: CredentialCheck = field(default_factory=CredentialCheck)
    _plans: dict[tuple, dict] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.index is None:
            self.index = RunsIndex(self.runs_dir, self.catalog)

    def plan(self, name: str, params: dict[str, str]) -> dict[str, Any]:
        """``bench plan``'s view of library procedure ``name`` with ``params`` (:func:`bench.web.launch.plan`),
        kept while the procedure and config files do not change."""
        from bench.web.launch import plan
        from bench.web.paths import procedure_path

        config = self.config or self.sim_config
        stamp = [p.stat().st_mtime_ns for p in (procedure_path(self.library, name), config) if p is not None]
        key = (name, tuple(sorted(params.items())), str(config), *stamp)
        with self._report_lock:
            if key in self._plans:
                return self._plans[key]
        out = plan(self.library, name, params, config)
        with self._report_lock:
            if len(self._plans) >= PLAN_CACHE:
                self._plans.pop(next(iter(self._plans)))
            self._plans[key] = out
        return out

    def report(self, path: Path) -> str:
        """The HTML report of ``path`` (``bench report``), kept while the file does not change."""
        from bench.report.run_report import build_report

        st = path.stat()
        key = (str(path), st.st_mtime_ns, st.st_size)
        with self._report_lock:
            if key in self._reports:
                return self._reports[key]
        html = redact(build_report(path))  # a file written before credentials were masked shows them masked
        with self._report_lock:
            self._reports = {k: v for k, v in self._reports.items() if k[0] != str(path)}
            self._reports[key] = html
        return html


def _json(data: Any, status: int = 200) -> JSONResponse:
    return JSONResponse(data, status_code=status, headers=SECURITY_HEADERS)


def _errors(exc: InputError | InputErrors, status: int = 400) -> JSONResponse:
    lines = [e.one_line() for e in exc.errors] if isinstance(exc, InputErrors) else [exc.one_line()]
    return _json({"errors": lines}, status)


class Limiters:
    """The worker-thread capacities of reads and of controls (made in the server's event loop)."""

    def __init__(self) -> None:
        self._made: tuple[anyio.CapacityLimiter, anyio.CapacityLimiter] | None = None

    def get(self) -> tuple[anyio.CapacityLimiter, anyio.CapacityLimiter]:
        if self._made is None:
            self._made = (anyio.CapacityLimiter(READ_THREADS), anyio.CapacityLimiter(CONTROL_THREADS))
        return self._made


def origin(request: Request) -> str:
    """``web <client address>``: the origin recorded with each control action."""
    from bench.operators import web_origin

    return web_origin(request.client.host if request.client else "")


def acting_person(station: "Station", body: dict, required: bool) -> str:
    """The name of the person acting from the page (the body's ``operator``): checked as a run's
    operator is, against the lab's list when it has one; ``""`` when not given and not ``required``
    (a stop is never refused for want of a name)."""
    from bench import operators

    name = body.get("operator") or ""  # typed already (START_FIELDS...): a name, or None/"" when not given
    if not name and not required:
        return ""
    return operators.resolve(name, station.operators, origin="", field="operator", required=True).name


def unit_of(station: Station, request: Request) -> Any:
    """The :class:`~bench.unit_history.UnitHistory` of the request's ``serial`` (and ``part``), from
    the station's runs index (:mod:`bench.web.runs_index`: the catalogue read, never written, and the
    run files of the runs directory not catalogued yet); figures only from files inside the runs
    directory. The index's warnings come first among the history's notes."""
    from bench.unit_history import unit_history

    q = query(request.query_params, UNIT_QUERY)
    warnings: list[str] = []

    def find(f: Any) -> list[dict[str, Any]]:
        rows, said = station.index.table(f)
        warnings.extend(w for w in said if w not in warnings)
        return rows

    h = unit_history(q["serial"], runs_dir=station.runs_dir, catalog=station.catalog, part=q["part"] or None, find=find,
                     only_runs_dir=True, field="serial")
    h.notes[:0] = warnings
    return h


def create_app(station: Station, *, bind_host: str = "127.0.0.1", allow_hosts: tuple[str, ...] = ()) -> Any:
    """The application serving ``station``, behind :class:`bench.web.guards.RequestGuard` (requests
    must name ``bind_host``, ``localhost`` or one of ``allow_hosts``)."""
    from bench.web.guards import WILDCARDS, RequestGuard, allowed_hosts

    return RequestGuard(_routes_app(station), allowed_hosts(bind_host, allow_hosts), any_ip=bind_host in WILDCARDS)


def _routes_app(station: Station) -> Starlette:
    """The Starlette application of ``station``'s pages and API."""

    limiters = Limiters()

    def guarded(fn: Callable[..., Response]) -> Callable:
        """A read endpoint, on the read threads: bad input is 400 with located lines, an unknown run 404."""
        async def endpoint(request: Request) -> Response:
            try:
                return await anyio.to_thread.run_sync(fn, request, limiter=limiters.get()[0])
            except (InputError, InputErrors) as exc:
                missing = isinstance(exc, InputError) and exc.message.startswith(("no run id", "no catalogued run"))
                return _errors(exc, 404 if missing else 400)
        return endpoint

    def control(fields: dict[str, Field]) -> Callable[[Callable[[Request, dict], Response]], Callable]:
        """A control endpoint, on the control threads: the token first (401 without, 403 wrong), then
        the JSON body (at most MAX_BODY_BYTES, its fields typed by ``fields``)."""
        def wrap(fn: Callable[[Request, dict], Response]) -> Callable:
            async def endpoint(request: Request) -> Response:
                auth = request.headers.get("authorization", "")
                if not auth.lower().startswith("bearer ") or not auth[7:].strip():
                    return _json({"errors": ["this action needs the station's token: Authorization: Bearer <token>"]}, 401)
                if not hmac.compare_digest(auth[7:].strip().encode(), station.token.encode()):
                    return _json({"errors": ["wrong token"]}, 403)
                try:
                    body = parse_body(await read_body(request), fields)
                    return await anyio.to_thread.run_sync(fn, request, body, limiter=limiters.get()[1])
                except BodyTooLarge:
                    return _json({"errors": [f"request body larger than {MAX_BODY_BYTES} bytes"]}, 413)
                except ClientDisconnect:  # the body never came (the server's request timeout): nobody to answer
                    return Response(status_code=400)
                except (InputError, InputErrors) as exc:
                    return _errors(exc)
            return endpoint
        return wrap

    def page(_request: Request) -> Response:
        return FileResponse(STATIC / "index.html", headers=SECURITY_HEADERS)

    def path_of(request: Request) -> Path:
        return run_path(station.runs_dir, query(request.query_params, RUN_QUERY)["id"])

    def api_session(_request: Request) -> Response:
        from bench.web.launch import lab_description

        return _json({"runs_dir": str(station.runs_dir), "config": str(station.config) if station.config else None,
                      "dry_run_config": str(station.config or station.sim_config or "") or None,
                      "real_lab": station.config is not None, "library": str(station.library), "operators": list(station.operators),
                      "lab": lab_description(station.config, station.sim_config)})

    def api_runs(request: Request) -> Response:
        table = runs_table(station.runs_dir, station.index, query(request.query_params, RUNS_QUERY))
        for r in table["runs"]:
            r["in_process"] = bool(r["id"]) and station.runs.get(r["id"]) is not None
        return _json(table)

    def api_run(request: Request) -> Response:
        path = path_of(request)
        data = run_page(path)
        data["id"] = request.query_params["id"]
        live = station.runs.get(data["id"])
        data["control"] = live.state() if live is not None else None
        return _json(redact_data(data))

    def api_live(request: Request) -> Response:
        rid = request.query_params.get("id", "")
        path = path_of(request)
        live = station.runs.get(rid)
        try:
            snap = station.live.snapshot(path)
            error = ""
        except InputError as exc:
            snap, error = None, exc.one_line()
        return _json(redact_data({"id": rid, "file": snap, "error": error, "control": live.state() if live is not None else None}))

    def api_stream(request: Request) -> Response:
        q = query(request.query_params, STREAM_QUERY)
        path = path_of(request)
        return _json(decimate(path, q["key"], q["column"], t0=q["t0"], t1=q["t1"], px=q["px"], cache=station.cache))

    def api_xy(request: Request) -> Response:
        q = query(request.query_params, XY_QUERY)
        path = path_of(request)
        return _json(xy_pairs(path, (q["xkey"], q["xcol"], q["xi"]), (q["ykey"], q["ycol"], q["yi"]), t0=q["t0"], t1=q["t1"],
                              points=q["points"], cache=station.cache))

    def api_report(request: Request) -> Response:
        return HTMLResponse(station.report(path_of(request)))

    def api_unit(request: Request) -> Response:
        from bench.unit_history import history_json

        return _json(redact_data(history_json(unit_of(station, request))))

    def api_unit_package(request: Request) -> Response:
        from bench.report.unit_package import build_package

        h = unit_of(station, request)
        name = "".join(c if c.isalnum() or c in "-_." else "_" for c in h.serial)
        return HTMLResponse(redact(build_package(h)), headers={**SECURITY_HEADERS,
                                                       "Content-Disposition": f'attachment; filename="{name}_acceptance.html"'})

    def api_file(request: Request) -> Response:
        path = path_of(request)
        secret = station.credentials.found_in(path)
        if secret:
            return _json({"errors": [f"{path.name} still holds a credential ({secret}; written before bench masked them): "
                                     "it is not served over the network; copy it from the station's disk, where it stays as it was"]}, 403)
        return FileResponse(path, filename=path.name, media_type="application/x-hdf5")

    def api_procedures(_request: Request) -> Response:
        from bench.web.launch import library

        return _json({"procedures": library(station.library)})

    def api_plan(request: Request) -> Response:
        from bench.web.requests import params

        q = query(request.query_params, PLAN_QUERY)
        return _json(station.plan(q["procedure"], params(q["params"])))

    def api_start(request: Request, body: dict) -> Response:
        from bench.web.launch import StartRequest, start

        req = StartRequest(procedure=body["procedure"], params=body["params"], unit=(body["unit"] or "").strip() or None,
                           dry_run=body["dry_run"], realtime=body["realtime"], accept_overdue=body["accept_overdue"],
                           operator=body["operator"] or "", origin=origin(request))
        live = start(req, library_dir=station.library, config_path=station.config, sim_config=station.sim_config,
                     runs_dir=station.runs_dir, catalog=station.catalog, runs=station.runs, busy=station.runs.busy_instruments())
        return _json({"id": live.run_id, "file": live.path.name})

    def _live_or_error(body: dict) -> Any:
        rid = body["id"]
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
        text = check_answer(body["answer"], body["confirm_abort"])
        person = acting_person(station, body, required=True)
        if not live.asker.answer(text, origin(request), person):
            return _json({"errors": ["no question is waiting for an answer"]}, 409)
        return _json({"ok": True})

    def api_pause(request: Request, body: dict) -> Response:
        live = _live_or_error(body)
        person = acting_person(station, body, required=False)
        want = body["paused"] if body["paused"] is not None else not live.runner.paused
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
        Route("/api/start", control(START_FIELDS)(api_start), methods=["POST"]),
        Route("/api/answer", control(ANSWER_FIELDS)(api_answer), methods=["POST"]),
        Route("/api/pause", control(PAUSE_FIELDS)(api_pause), methods=["POST"]),
        Route("/api/stop", control(STOP_FIELDS)(api_stop), methods=["POST"]),
        Mount("/static", StaticFiles(directory=STATIC), name="static"),
    ]

    @contextlib.asynccontextmanager
    async def lifespan(_app: Starlette) -> AsyncIterator[None]:
        yield
        # the server stops (Ctrl-C): runs started here are stopped like a Ctrl-C of 'bench run'
        await anyio.to_thread.run_sync(station.runs.stop_all, "the web station stopped")
        station.index.close()

    return Starlette(routes=routes, lifespan=lifespan)

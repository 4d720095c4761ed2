"""Starting a run from the web station: the procedure library, ``bench plan``'s view, the same
validation as ``bench run`` (located messages), and the run itself on a worker thread.

The checks are the ones ``bench run`` makes, through the same functions (``load_checked``,
``run_identity``, ``overdue_calibrations``, ``check_destination``, ``start_run``); an instrument past
its calibration due date needs the form's explicit confirmation (recorded as
``--accept-overdue-calibration`` is). The plan is ``bench plan``'s own output
(:func:`bench.plan_view.plan_text`), computed in this process: one process per request (12 at once
took 22 s) was a way to slow the station down without the token.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bench.errors import InputError, InputErrors
from bench.web.paths import PROCEDURE_SUFFIXES, procedure_path, run_id

PLAN_COLUMNS = 120
"""Terminal width ``bench plan`` lays its table out for."""


@dataclass
class StartRequest:
    """What the start form sends: procedure (name in the library), parameter overrides (name ->
    value text with units), unit serial, ``dry_run`` (simulators) with ``realtime`` (wall-clock pace),
    ``accept_overdue`` (confirm instruments past their calibration due date)."""

    procedure: str
    params: dict[str, str]
    unit: str | None = None
    dry_run: bool = True
    realtime: bool = True
    accept_overdue: bool = False
    operator: str = ""
    """Who runs it (the form's operator field): required; one of the lab's ``operators:`` when it lists them."""
    origin: str = "web"
    """Where the request came from: ``web ADDRESS`` (the socket's peer)."""


def lab_description(config: Path | None, sim_config: Path | None) -> dict[str, Any]:
    """What the start page says about the lab: ``real`` (a hardware config: real runs possible),
    ``config`` (the file runs use), ``sim_only`` (its ``mode: sim``: every run is a dry-run),
    ``text`` (one sentence)."""
    from bench.config import load_config

    path = config or sim_config
    if path is None:
        return {"real": False, "config": None, "sim_only": True, "text": "no lab config: runs cannot be started"}
    try:
        mode = load_config(path).mode
    except (InputError, InputErrors) as exc:
        return {"real": False, "config": str(path), "sim_only": True, "text": f"the lab config cannot be read: {errors_of(exc)[0]}"}
    if config is None or mode == "sim":
        return {"real": False, "config": str(path), "sim_only": True,
                "text": f"simulated lab ({path}): every run here is a DRY-RUN on simulated instruments, not acceptance evidence"}
    return {"real": True, "config": str(path), "sim_only": False,
            "text": f"real lab ({path}): runs drive its instruments; a dry-run uses its simulators"}


def errors_of(exc: InputError | InputErrors) -> list[str]:
    """The located one-line messages of an input error, as the CLI prints them."""
    return [e.one_line() for e in exc.errors] if isinstance(exc, InputErrors) else [exc.one_line()]


def library(directory: Path) -> list[dict[str, Any]]:
    """The procedures of the library directory: ``name`` (file name), ``procedure`` (its name),
    ``title``, ``description``, ``instruments``, ``parameters`` (name -> default as written),
    ``parameter_notes`` (name -> the comment written after it in the file), ``prompts`` (the
    operator prompts ``bench plan`` counts: prompts, remounts, shaker runs), ``steps``, or ``error``
    (one line)."""
    from bench.procedure import load_procedure

    out = []
    if not directory.is_dir():
        return out
    for p in sorted(x for x in directory.iterdir() if x.suffix in PROCEDURE_SUFFIXES and x.is_file()):
        item: dict[str, Any] = {"name": p.name}
        try:
            proc = load_procedure(p)
            item.update(procedure=proc.name, title=proc.title, description=proc.description or "",
                        instruments=list(proc.instruments), parameters={k: _param_text(v) for k, v in proc.parameters.items()},
                        parameter_notes=parameter_notes(proc.text, list(proc.parameters)), prompts=proc.estimate().prompts,
                        steps=len(proc.steps))
        except (InputError, InputErrors) as exc:
            item["error"] = errors_of(exc)[0]
        out.append(item)
    return out


_PARAM_LINE = re.compile(r"^(?P<indent>\s+)(?P<name>[A-Za-z_][A-Za-z0-9_]*)\s*:(?P<rest>.*)$")


def parameter_notes(text: str, names: list[str]) -> dict[str, str]:
    """What the procedure file says about each parameter: the comment after it on its line
    (``hot: 66 degC  # IV.C.1: 66 °C hot soak``), else ``""``. Only the top-level ``parameters:``
    block is read; a ``#`` inside quotes is not a comment."""
    notes: dict[str, str] = {}
    inside = False
    for line in text.splitlines():
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        if not line[0].isspace():
            inside = line.split("#", 1)[0].strip() == "parameters:"
            continue
        m = _PARAM_LINE.match(line)
        if inside and m and m.group("name") in names and m.group("name") not in notes:
            notes[m.group("name")] = _comment(m.group("rest"))
    return {n: notes.get(n, "") for n in names}


def _comment(rest: str) -> str:
    quote = ""
    for i, c in enumerate(rest):
        if quote:
            quote = "" if c == quote else quote
        elif c in "'\"":
            quote = c
        elif c == "#" and (i == 0 or rest[i - 1].isspace()):
            return rest[i + 1:].strip()
    return ""


def _param_text(v: Any) -> str:
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_param_text(x) for x in v) + "]"
    return str(v)


def plan(library_dir: Path, name: str, params: dict[str, str], config: Path | None) -> dict[str, Any]:
    """``bench plan``'s view of the procedure: ``ok``, ``text`` (its table, :data:`PLAN_COLUMNS` wide),
    ``errors`` (its located lines, as ``bench plan`` prints them)."""
    from bench.plan_view import plan_text
    from bench.validate import load_checked

    path = procedure_path(library_dir, name)
    try:
        procedure, cfg = load_checked(path, config, params)
    except (InputError, InputErrors) as exc:
        return {"ok": False, "text": "", "errors": errors_of(exc)}
    return {"ok": True, "text": plan_text(procedure, cfg, PLAN_COLUMNS), "errors": []}


def start(req: StartRequest, *, library_dir: Path, config_path: Path | None, sim_config: Path | None, runs_dir: Path,
          catalog: str | None, runs: Any, busy: set[str]) -> Any:
    """Validate ``req`` as ``bench run`` would and start the run on a worker thread; returns the
    :class:`~bench.web.live.LiveRun`. A dry-run uses ``config_path`` (its simulators) or, without one,
    ``sim_config``; a real run needs ``config_path``. ``busy``: instruments of the real lab held by
    other runs (refused). The operator is the request's (:func:`bench.operators.resolve`: required,
    one of the lab's list when it has one), recorded with the request's origin. Raises
    :class:`InputError`/:class:`InputErrors` (located) for bad input."""
    from bench.identity import utc_today
    from bench.procedure.estimate import run_file_bytes
    from bench.record import check_destination
    from bench.runner.session import start_run
    from bench.runner.unit_identity import overdue_calibrations, run_identity
    from bench.validate import load_checked
    from bench.web.live import LiveRun, PageProgress, WebAsker, WebOperator

    from bench import operators

    path = procedure_path(library_dir, req.procedure)
    cfg = config_path if config_path is not None else (sim_config if req.dry_run else None)
    if cfg is None:
        raise InputError("a run on the real lab needs the server started with --config LAB.yaml", None, "--config")
    procedure, config = load_checked(path, cfg, req.params)
    who = operators.resolve(req.operator, config.operators, origin=req.origin, field="operator", allowed_at=config.operators_location,
                            required=True)
    sim = req.dry_run or config.mode == "sim"
    if sim:
        no_sim = [n for n in procedure.instruments if config.instruments[n].sim is None]
        if no_sim:
            raise InputErrors([InputError("has no 'sim' section, so it cannot be simulated (dry-run)", config.instruments[n].location, n)
                               for n in no_sim])
    else:
        taken = sorted(set(procedure.instruments) & busy)
        if taken:
            raise InputError(f"instrument(s) {', '.join(taken)} are in use by another run on this station", None, "instruments")
        from bench.lab import check_ports

        check_ports(config, procedure.instruments)  # an absent port: said before a run file exists
    identity = run_identity(procedure, config, unit=req.unit or None)
    overdue = overdue_calibrations(config, procedure.instruments, utc_today())
    if overdue and not req.accept_overdue:
        raise InputErrors([InputError(f"{o.describe()}; confirm it on the form to run anyway", o.location, o.instrument) for o in overdue])
    check_destination(runs_dir, run_file_bytes(procedure))
    asker, progress = WebAsker(), PageProgress()
    session = start_run(procedure, config, procedure_path=path, config_path=cfg, runs_dir=runs_dir, sim=sim,
                        realtime=sim and req.realtime, operator=WebOperator(asker), progress=progress,
                        operator_name=who.name, operator_origin=who.origin, identity=identity, overdue=overdue,
                        accept_overdue=req.accept_overdue, catalog=catalog)
    rid = run_id(runs_dir, session.recorder.path) or session.recorder.path.name
    live = LiveRun(rid, session.recorder.path, session, asker, progress, tuple(procedure.instruments), sim)
    runs.launch(live)
    return live

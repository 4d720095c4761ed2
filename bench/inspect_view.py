"""``bench inspect RUN.h5`` and the summary at the end of ``bench run``: a run as terminal tables
that read at 80 columns.

* A run that is not on real instruments opens with its banner (``DRY-RUN: simulated instruments,
  not acceptance evidence``, :mod:`bench.run_mode`).
* Every number carries its unit (:mod:`bench.quantity_format`): durations, check values and their
  limits in the check's display units (a 5 % limit stays ``-5 .. 5 %``).
* Checks: one table (what, value, limits, outcome) that fits 80 columns without splitting.
* Events: one table (run time, step, event, message) with the message wrapped; answers and control
  actions as sentences (:func:`bench.event_text.event_text`), never raw JSON.
* Every text of the file is data: its control characters (escape sequences, line breaks) are shown
  as visible escapes, never acted on (:mod:`bench.terminal_text`), including the texts decoded from
  the JSON of check and operator events.

Units: run times as H:MM:SS (and s in the steps' durations).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Sequence

from rich.console import Console
from rich.table import Table
from rich.text import Text

from bench.event_text import event_text
from bench.quantity_format import fmt_hms, fmt_quantity, fmt_range, fmt_seconds
from bench.record import layout
from bench.record.checks import CheckResult, check_counts, check_results, checks_verdict, display_value
from bench.run_mode import banner, is_evidence, mode_word
from bench.terminal_text import printable, printable_data
from bench.termtable import fit_tables

if TYPE_CHECKING:  # pragma: no cover
    from bench.record.reader import RunSummary

STATUS_STYLE = {layout.STATUS_COMPLETED: "bold green", layout.STATUS_RUNNING: "bold cyan", layout.STATUS_CRASHED: "bold red",
                layout.STATUS_WAITING: "bold magenta", layout.STATUS_ABORTED: "bold red", layout.STATUS_FAILED: "bold red"}
OUTCOME_STYLE = {"passed": "green", "done": "green", "failed": "red", "aborted": "red", "interrupted": "yellow", "running": "cyan",
                 layout.OUTCOME_RECORDED: "blue"}
BANNER_STYLE = "bold black on yellow"
EVENT_DATA_SHOWN = 16
"""Bytes of an event's data ``bench inspect --traffic`` shows (in hex), the rest counted."""
CHECKSUMS_TEXT = {
    "all": "Fletcher-32 on every stream and event chunk, not read by this summary (bench inspect --verify reads them all)",
    "some": "Fletcher-32 on some datasets only (bench inspect --verify)",
    "none": "none: written before checksums, the data cannot be verified",
}
"""What the ``checksums`` row of ``bench inspect`` says for :attr:`RunSummary.checksums`."""


def banner_text(mode: str | None) -> Text | None:
    """The mode's banner (:func:`bench.run_mode.banner`) as a loud line, None for a real run."""
    b = banner(mode)
    return Text(f" {b} ", style=BANNER_STYLE) if b else None


# ---- checks ---------------------------------------------------------------------------------------
def check_what(c: CheckResult) -> str:
    """``scale_factor_error of acs_board.gyro.z over func_z_*``."""
    return f"{c.statistic} of {c.signal}" + (f" over {c.window}" if c.window else "")


def check_value(c: CheckResult) -> str:
    """The check's value in its display units: ``0.1256 %``, ``-0.3483 deg/s``, ``-`` if none."""
    value, units = display_value(c.statistic, c.value, c.units)
    return fmt_quantity(value, units)


def check_limits(c: CheckResult) -> str:
    """The check's limits in its display units: ``-5 .. 5 %``, ``≤ 0.5 deg/s``, ``|Δ sf_pre| ≤ 0.5 %``,
    ``none`` without limits."""
    if not c.limited:
        return "none"
    lo, units = display_value(c.statistic, c.minimum, c.units)
    hi, _ = display_value(c.statistic, c.maximum, c.units)
    parts = [fmt_range(lo, hi, units)] if lo is not None or hi is not None else []
    if c.reference and c.max_difference is not None:
        d, _ = display_value(c.statistic, c.max_difference, c.units)
        parts.append(f"|Δ {c.reference}| ≤ {fmt_quantity(d, units)}")
    return ", ".join(parts)


def check_rows(checks: Sequence[CheckResult], *, evidence: bool = True) -> tuple[list[str], list[list[Any]]]:
    """Headers and rows of the checks table: the check (its name, then what it computes, dim),
    value, limits, outcome; 80 columns hold it whole. The outcome of a run that is not evidence is
    not coloured as a pass."""
    rows = []
    for c in checks:
        style = OUTCOME_STYLE.get(c.outcome, "") if evidence or c.outcome != "passed" else ""
        name = Text(printable(c.name))
        name.append(f"\n{printable(check_what(c))}", style="dim")
        rows.append([name, printable(check_value(c)), printable(check_limits(c)), Text(printable(c.outcome), style=style)])
    return ["check", "value", "limits", "outcome"], rows


# ---- the summary ----------------------------------------------------------------------------------
def identity_rows(summary: "RunSummary") -> list[tuple[str, Text | str]]:
    """Header rows ``unit`` (serial, part, revision) and ``station``; ``-`` when not recorded."""
    u = summary.identity
    unit = u.get(layout.ATTR_UNIT_SERIAL, "") or "-"
    more = [f"{label} {u[key]}" for label, key in (("part", layout.ATTR_UNIT_PART), ("revision", layout.ATTR_UNIT_REVISION)) if u.get(key)]
    return [("unit", ", ".join([unit, *more])), ("station", u.get(layout.ATTR_STATION, "") or "-")]


def operator_text(attrs: dict[str, Any]) -> str:
    """``alice (cli root@pts/3)``: the run's operator and where the name came from."""
    from bench.operators import describe

    return describe(str(attrs.get(layout.ATTR_OPERATOR, "")), str(attrs.get(layout.ATTR_OPERATOR_ORIGIN, "") or ""))


def _render_instrument_identity(summary: "RunSummary", console: Console) -> None:
    """When the lab config declared any: each instrument's reported and declared serial and
    firmware, and its calibration due date (``OVERDUE`` if before the run's start date)."""
    declared = {n: i for n, i in summary.instrument_identity.items() if i.config_serial or i.config_firmware or i.calibration_due}
    if not declared:
        return
    t = Table(title="Instrument identity (reported / lab config)")
    for col in ("name", "serial", "firmware", "calibration due"):
        t.add_column(col)
    for name, i in declared.items():
        due = Text(i.calibration_due or "-")
        if i.calibration_overdue:
            due = Text(f"{i.calibration_due} OVERDUE", style="bold red")
            if i.overdue_confirmation:
                due.append(f" confirmed: {i.overdue_confirmation}", style="yellow")
        t.add_row(Text(name), Text(f"{i.serial or '-'} / {i.config_serial or '-'}"),
                  Text(f"{i.firmware or '-'} / {i.config_firmware or '-'}"), due)
    console.print(t)


def _checksum_rows(summary: "RunSummary") -> list[tuple[str, Text | str]]:
    rows: list[tuple[str, Text | str]] = []
    if summary.checksums:
        rows.append(("checksums", Text(CHECKSUMS_TEXT.get(summary.checksums, summary.checksums),
                                       style="yellow" if summary.checksums != "all" else "")))
    for s in summary.streams:
        if s.damage:
            rows.append(("damaged", Text(f"stream {s.key}: {s.damage} (bench inspect --verify lists every damaged chunk)",
                                         style="bold red")))
    return rows


def render_summary(summary: "RunSummary", console: Console, max_events: int = 40, traffic: bool = False) -> None:
    """Print the run: its banner (a run not on real instruments), header (status ``waiting`` while a
    live run waits for the operator), instruments, streams, steps, checks (value with units, limits,
    outcome), the instrument traffic summarised per instrument, and the last ``max_events`` other
    events with counts by kind (``traffic``: list the ``command``/``reply`` events too). The file's
    texts are shown with their control characters escaped (:func:`bench.terminal_text.printable_data`)."""
    summary = printable_data(summary)
    a = summary.attrs
    mode = str(a.get(layout.ATTR_MODE, ""))
    loud = banner_text(mode)
    if loud is not None:
        console.print(loud)
    head = Table.grid(padding=(0, 2))
    head.add_column(style="bold")
    head.add_column(overflow="fold")
    status = Text(summary.live_status, style=STATUS_STYLE.get(summary.live_status, "bold"))
    if summary.status_detail:
        status.append(f"  {summary.status_detail}", style="dim" if summary.status == layout.STATUS_RUNNING else "red")
    rows: list[tuple[str, Text | str]] = [
        ("procedure", f"{a.get(layout.ATTR_PROCEDURE_NAME, '')} ({a.get(layout.ATTR_PROCEDURE_PATH, '')})"),
        ("file", printable(summary.path)),
        ("status", status),
        ("started", str(a.get(layout.ATTR_STARTED_UTC, ""))),
        ("ended", str(a.get(layout.ATTR_ENDED_UTC, "")) or "-"),
        ("mode", Text(f"{mode_word(mode)} ({mode})", style="" if is_evidence(mode) else BANNER_STYLE)),
        ("operator", operator_text(a)),
        ("host", str(a.get(layout.ATTR_HOST, ""))),
        ("software", f"bench {a.get(layout.ATTR_SOFTWARE_VERSION, '')}, run-file format {a.get(layout.ATTR_FORMAT_VERSION, '')}"),
        ("config", str(a.get(layout.ATTR_CONFIG_PATH, ""))),
    ]
    rows += identity_rows(summary)
    if summary.abort_reason:
        rows.append(("abort reason", Text(summary.abort_reason, style="red")))
    for w in summary.warnings:
        rows.append(("warning", Text(w, style="yellow")))
    rows += _checksum_rows(summary)
    for k, v in rows:
        head.add_row(k, v if isinstance(v, Text) else Text(v))
    console.print(head)
    _render_instrument_identity(summary, console)

    def show(headers: list[str], rows: list[list[Any]], title: str, prose: tuple[int, ...] = (), key: int = 1) -> None:
        for t in fit_tables(headers, rows, console.width, title=title, key=key, prose=prose):
            console.print(t)

    if summary.instruments:
        show(["name", "identity"], [[name, ", ".join(f"{k}={v}" for k, v in info.items())] for name, info in summary.instruments.items()],
             "Instruments", prose=(1,))
    if summary.streams:
        rows = []
        for s in summary.streams:
            span = f"{fmt_hms(s.t_start_s)} .. {fmt_hms(s.t_end_s)}" if s.t_start_s is not None and s.t_end_s is not None else "no rows"
            cols = ", ".join(f"{n}{list(s.shapes[n]) if s.shapes.get(n) else ''} ({u})" for n, u in s.columns.items())
            rate = f", {fmt_quantity(s.rate_hz, 'Hz')}" if s.rate_hz is not None else ""
            rows.append([s.key, f"{s.rows} rows{rate}\n{span}", cols])
        show(["stream", "rows, run time", "columns (units)"], rows, "Streams", prose=(0, 2))
    if summary.steps:
        show(["#", "step", "type", "outcome", "took", "detail"],
             [[str(s.index + 1), s.name, s.type, Text(s.outcome, style=OUTCOME_STYLE.get(s.outcome, "")),
               fmt_seconds(s.duration_s), s.detail] for s in summary.steps],
             "Steps", prose=(1, 5))
    checks = check_results(summary)
    if checks:
        headers, rows = check_rows(checks, evidence=is_evidence(mode))
        verdict = checks_verdict(check_counts(c.outcome for c in checks))
        show(headers, rows, f"Checks: {verdict}" + ("" if is_evidence(mode) else f" ({mode_word(mode)})"), prose=(0, 2), key=1)
    if summary.traffic:
        show(["instrument traffic"], [[tr.describe()] for tr in summary.traffic.values()],
             "Instrument traffic (command and reply events, kept for replay; --traffic lists them)", prose=(0,))
    render_events(summary, console, max_events, traffic)


def render_events(summary: "RunSummary", console: Console, max_events: int, traffic: bool) -> None:
    """The last ``max_events`` events (other than instrument traffic unless ``traffic``) as one
    table: run time, step, event (kind and source), message (answers and control actions as sentences)."""
    listed = summary.events if traffic else summary.meaningful_events
    n = sum(summary.event_counts.values()) if traffic else sum(
        v for k, v in summary.event_counts.items() if k not in layout.TRAFFIC_EVENT_KINDS)
    shown = listed[-max_events:] if max_events > 0 else []
    counts = ", ".join(f"{k} {v:,}" for k, v in sorted(summary.event_counts.items()))
    what = "events" if traffic else "events other than instrument traffic"
    rows = []
    for e in shown:
        kind = Text(e.kind, style="red" if e.kind in ("error", "fault", "abort") else "")
        kind.append(f" {e.source}", style="dim")
        message = event_text(e.kind, e.source, e.message)
        if traffic and e.data and e.kind in layout.TRAFFIC_EVENT_KINDS:  # the frames' bytes
            message += " [" + e.data[:EVENT_DATA_SHOWN].hex(" ") + (f" +{len(e.data) - EVENT_DATA_SHOWN} B" if len(e.data) > EVENT_DATA_SHOWN else "") + "]"
        rows.append([fmt_hms(e.t_s), str(e.step + 1) if e.step >= 0 else "", kind, message])
    title = f"Events (last {len(shown)} of {n:,} {what}; {counts or 'none'})"
    for t in fit_tables(["run time", "step", "event", "message"], rows, console.width, title=title, key=1, prose=(2, 3)):
        console.print(t)

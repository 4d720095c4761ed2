"""What a run's checks say: their results read back from a run file, and the verdict of a run.

A check with limits (``min``, ``max``, or ``reference`` with ``max_difference``) ends ``passed`` or
``failed``. A check without limits only stores its value: it ends ``recorded``, which is no verdict
(as in OpenHTF, where a measurement without a validator does not pass). The runner, ``bench run``'s
summary, ``bench inspect``, ``bench watch`` and the HTML report all count checks with
:func:`check_counts` and say what the counts mean with :func:`checks_verdict`.

Units: check values and limits in the units of their signal (``slope``: per s; ``scale_factor_error``:
a fraction, shown in %), run times in s.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Iterable, Mapping

from bench.record import layout

if TYPE_CHECKING:  # pragma: no cover
    from bench.record.reader import RunSummary


def has_limits(minimum: float | None, maximum: float | None, max_difference: float | None = None,
               reference: str | None = None) -> bool:
    """Whether a check gives a verdict: a lower or upper limit, or a reference with an allowed difference."""
    return minimum is not None or maximum is not None or (bool(reference) and max_difference is not None)


def check_counts(outcomes: Iterable[str]) -> dict[str, int]:
    """``{"passed": n, "failed": n, "recorded": n}`` of the checks' outcomes (others are ignored)."""
    out = {k: 0 for k in layout.CHECK_OUTCOMES}
    for o in outcomes:
        if o in out:
            out[o] += 1
    return out


def _n_checks(n: int) -> str:
    return f"{n} check{'s' if n != 1 else ''}"


def checks_verdict(counts: Mapping[str, int]) -> str:
    """One sentence for the counts of :func:`check_counts`, e.g. ``all 3 checks passed``,
    ``3 checks recorded without limits; no verdict`` or ``1 check failed, 2 passed; 1 recorded without
    limits (no verdict)``."""
    passed, failed, recorded = (counts.get(k, 0) for k in layout.CHECK_OUTCOMES)
    if not passed and not failed:
        return f"{_n_checks(recorded)} recorded without limits; no verdict" if recorded else "no checks"
    if failed:
        text = f"{_n_checks(failed)} failed" + (f", {passed} passed" if passed else "")
    else:
        text = (f"all {_n_checks(passed)} passed" if passed > 1 else "the check passed") if not recorded else f"{_n_checks(passed)} passed"
    return text + (f"; {recorded} recorded without limits (no verdict)" if recorded else "")


@dataclass
class CheckResult:
    """One check of the run: from its ``check`` event (name, signal, statistic, window pattern,
    value, limits, reference check) and its step's outcome and message."""

    name: str
    step: int
    outcome: str
    signal: str = ""
    statistic: str = ""
    window: str = ""
    value: float | None = None
    minimum: float | None = None
    maximum: float | None = None
    reference: str | None = None
    basis: str = ""
    message: str = ""
    max_difference: float | None = None
    units: str = ""
    """Units of the signal (the check event's, else the run's stream columns); values in display units
    through :func:`display_value`."""

    @property
    def limited(self) -> bool:
        """Whether the check has limits (:func:`has_limits`)."""
        return has_limits(self.minimum, self.maximum, self.max_difference, self.reference)


def check_from_result(d: Mapping[str, Any], step: int, outcome: str, message: str = "", units: str = "") -> CheckResult:
    """A :class:`CheckResult` from a check's result mapping (the data of its ``check`` event, an
    entry of the runner's results) at 0-based ``step``; ``units`` if the mapping has none."""
    return CheckResult(
        name=str(d.get("name", "")), step=step, outcome=outcome, signal=str(d.get("signal", "")),
        statistic=str(d.get("statistic", "")), window=str(d.get("window", "")), value=_float(d.get("value")),
        minimum=_limit(d.get("min")), maximum=_limit(d.get("max")), reference=d.get("reference") or None,
        basis=str(d.get("basis", "")), message=message, max_difference=_limit(d.get("max_difference")),
        units=str(d.get("units") or units),
    )


def check_results(summary: "RunSummary") -> list[CheckResult]:
    """Every check step (and built-in test) in step order, with what its event recorded. A check
    without limits that a runner from before the ``recorded`` outcome wrote as ``passed`` reads
    ``recorded``."""
    data: dict[int, dict[str, Any]] = {}
    for e in summary.events:
        if e.kind == layout.EVENT_CHECK and e.data:
            try:
                d = json.loads(e.data.decode("utf-8"))
            except (UnicodeDecodeError, json.JSONDecodeError):
                continue
            if isinstance(d, dict):
                data[e.step] = d
    out = []
    for s in summary.steps:
        if s.type not in ("check", "bit"):
            continue
        d = {"statistic": s.type, **data.get(s.index, {}), "name": s.name}
        c = check_from_result(d, s.index, s.outcome, s.detail, signal_units(summary, str(d.get("signal", ""))))
        if c.outcome == layout.OUTCOME_PASSED and s.index in data and c.minimum is None and c.maximum is None and not c.reference:
            c.outcome = layout.OUTCOME_RECORDED  # written by a runner from before the recorded outcome
        out.append(c)
    return out


def _float(v: Any) -> float | None:
    try:
        return None if v is None else float(v)
    except (TypeError, ValueError):
        return None


def _limit(v: Any) -> float | None:
    """A check limit: a number, None when absent or infinite (no limit on that side)."""
    x = _float(v)
    return x if x is not None and math.isfinite(x) else None


def signal_units(summary: "RunSummary", signal: str) -> str:
    """Units of ``INSTRUMENT.COLUMN[.AXIS]`` from the run's stream columns, ``""`` if unknown."""
    parts = signal.split(".")
    if len(parts) < 2:
        return ""
    inst, col = parts[0], parts[1]
    for s in summary.streams:
        if (s.key == inst or s.key.startswith(inst + "/")) and col in s.columns:
            return s.columns[col]
    return ""


def display_value(statistic: str, value: float | None, units: str) -> tuple[float | None, str]:
    """A check value in display units: scale-factor errors in %, slopes per s, counts bare."""
    if statistic == "scale_factor_error":
        return (None if value is None else 100.0 * value), "%"
    if statistic == "slope":
        return value, f"{units}/s" if units else "1/s"
    if statistic in ("count", "bit"):
        return value, ""
    return value, units


def describe_limits(check: CheckResult) -> str:
    """The check's limits as text in display units (:func:`display_value`): ``-0.1 .. 0.1 deg/s``,
    ``≤ 0.5 %``, ``|Δ sf_pre| ≤ 0.5 %``; ``none`` for a check without limits."""
    if not check.limited:
        return "none"
    units = check.units
    lo = display_value(check.statistic, check.minimum, units)[0]
    hi, u = display_value(check.statistic, check.maximum, units)
    u = f" {u}" if u else ""
    parts = []
    if lo is not None and hi is not None:
        parts.append(f"{lo:.6g} .. {hi:.6g}{u}")
    elif lo is not None:
        parts.append(f"≥ {lo:.6g}{u}")
    elif hi is not None:
        parts.append(f"≤ {hi:.6g}{u}")
    if check.reference and check.max_difference is not None:
        d = display_value(check.statistic, check.max_difference, units)[0]
        parts.append(f"|Δ {check.reference}| ≤ {d:.6g}{u}")
    return ", ".join(parts)


def check_json(check: CheckResult) -> dict[str, Any]:
    """A check as a JSON-ready mapping: ``value``, ``min``, ``max``, ``max_difference`` in display
    units (:func:`display_value`; ``units``), NaN as None, ``step`` 1-based: the check fields of
    ``bench inspect --json`` and ``bench run --json``."""
    units = check.units
    value, display_units = display_value(check.statistic, check.value, units)
    return {
        "name": check.name, "step": check.step + 1, "outcome": check.outcome, "signal": check.signal,
        "statistic": check.statistic, "window": check.window, "value": _finite(value), "units": display_units,
        "min": _finite(display_value(check.statistic, check.minimum, units)[0]),
        "max": _finite(display_value(check.statistic, check.maximum, units)[0]),
        "reference": check.reference, "max_difference": _finite(display_value(check.statistic, check.max_difference, units)[0]),
        "limits": describe_limits(check), "basis": check.basis, "message": check.message,
    }


def _finite(v: float | None) -> float | None:
    return v if v is not None and math.isfinite(v) else None


def procedure_info(summary: "RunSummary") -> dict[str, Any]:
    """The ``procedure`` event's data: parameters in force, clock (virtual/wall), planned steps…"""
    for e in summary.events:
        if e.kind == "procedure" and e.data:
            try:
                info = json.loads(e.data.decode("utf-8"))
            except (UnicodeDecodeError, json.JSONDecodeError):
                return {}
            return info if isinstance(info, dict) else {}
    return {}


@dataclass
class Verdict:
    """The run's verdict: ``word`` (PASSED, FAILED, NO VERDICT or INCOMPLETE) and the ``reasons``
    behind it, one sentence each."""

    word: str
    reasons: list[str]


def run_verdict(summary: "RunSummary", checks: list["CheckResult"] | None = None) -> Verdict:
    """FAILED when a check or another step failed (even in a run that did not finish); else
    INCOMPLETE when the run did not run to its end (aborted, crashed, still running, or fewer steps
    executed than planned); else NO VERDICT when no check has limits (none, or only recorded values);
    else PASSED. ``checks``: :func:`check_results` of the summary (read when not given). The one
    verdict of a run: the report shows it, the catalogue stores it (lower case)."""
    checks = check_results(summary) if checks is None else checks
    judged = [c for c in checks if c.outcome in ("passed", "failed")]
    failed = [c for c in judged if c.outcome == "failed"]
    recorded = [c for c in checks if c.outcome == layout.OUTCOME_RECORDED]
    failed_steps = [s for s in summary.steps if s.type not in ("check", "bit") and s.outcome == "failed"]
    unfinished = []
    if summary.status != layout.STATUS_COMPLETED:
        why = summary.abort_reason or summary.status_detail
        unfinished.append(f"the run is {summary.status}" + (f": {why}" if why else ""))
    planned = procedure_info(summary).get("steps")
    if isinstance(planned, int) and len(summary.steps) < planned:
        unfinished.append(f"{len(summary.steps)} of {planned} steps executed")
    cut = [s for s in summary.steps if s.outcome in ("interrupted", "running", "aborted")]
    if cut:
        unfinished.append("step " + ", ".join(f"{s.index + 1} {s.name} {s.outcome}" for s in cut))
    extra = [f"{len(recorded)} value(s) recorded without limits (no verdict)"] if recorded else []
    if failed or failed_steps:
        reasons = [f"{len(failed)} of {len(judged)} checks failed: {', '.join(c.name for c in failed)}"] if failed else []
        reasons += [f"step {s.index + 1} {s.name} failed: {s.detail}" for s in failed_steps]
        return Verdict("FAILED", reasons + unfinished + extra)
    if unfinished:
        return Verdict("INCOMPLETE", unfinished + ([f"{len(judged)} checks passed before that"] if judged else []) + extra)
    if not judged:
        return Verdict("NO VERDICT", ["no check in this run has limits" if checks else "this run has no checks"] + extra)
    return Verdict("PASSED", [f"all {len(judged)} checks with limits passed" if len(judged) > 1 else "the check with limits passed"] + extra)

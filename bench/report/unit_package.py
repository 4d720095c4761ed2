"""A unit's acceptance data package: one self-contained HTML file (``bench unit SN12 --html``, the
web station's unit page "export"): the unit and its lot, every run (dry-runs marked), and each key
figure plotted against date and against the other units of the same part number, with whether the
unit is an outlier of its lot (:mod:`bench.unit_history`). Figures are inline PNG, as in the run
report: no external file, script or font.

Only runs on real instruments are evidence: dry-run points are drawn hollow, listed with their mode,
and the package says how many there are at its top.
"""

from __future__ import annotations

from datetime import datetime, timezone
from typing import Any

from bench import __version__
from bench.quantity_format import fmt_quantity, fmt_range
from bench.report.html import Cell, esc, figure_png, page, plt, table
from bench.run_mode import mode_word, verdict_text
from bench.unit_history import OUTLIER_Z, Figure, UnitHistory

REAL_COLOUR = "#1f5fa8"
UNIT_COLOUR = "#c62828"
LOT_COLOUR = "#777777"


def build_package(h: UnitHistory) -> str:
    """The package of history ``h`` as one HTML document."""
    sections = [("Unit and lot", _section_unit(h)), ("Runs", _section_runs(h))]
    for f in h.figures:
        sections.append((f"{f.name} [{f.units}]" if f.units else f.name, _section_figure(h, f)))
    if not h.figures:
        sections.append(("Key figures", '<p class="note">none of the runs recorded a check of bias, scale-factor error or noise on '
                                        'a sensor axis</p>'))
    generated = datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
    dry = (f"{h.dry_runs} of {len(h.runs)} runs of {h.serial} are DRY-RUNs or replays (hollow points, marked rows): "
           "not acceptance evidence") if h.dry_runs else ""
    return page(f"Acceptance data package: unit {h.serial}", sections,
                subtitle=f"part {h.part or 'not recorded'}; generated {generated} by bench {__version__}", banner=dry)


def _section_unit(h: UnitHistory) -> str:
    real = [r for r in h.runs if r.evidence]
    rows: list[list[Any]] = [
        ["serial", h.serial], ["part", h.part or Cell("not recorded", "note")],
        ["revisions", ", ".join(sorted({r.revision for r in h.runs if r.revision})) or Cell("not recorded", "note")],
        ["runs", f"{len(h.runs)} ({len(real)} on real instruments, {h.dry_runs} dry-runs or replays)"],
        ["latest real verdict", (verdict_text(real[-1].verdict, real[-1].mode) if real and real[-1].verdict else
                                 Cell("no run on real instruments", "warn"))],
        ["lot", f"{len(h.lot_units)} other unit(s) of {h.part}: {', '.join(h.lot_units)}" if h.lot_units else Cell("none", "note")],
        ["outliers", ", ".join(f.name for f in h.figures if f.outlier) or "none"],
    ]
    out = table(["item", "value"], rows, left=2)
    if h.notes:
        out += "<ul>" + "".join(f'<li class="note">{esc(n)}</li>' for n in h.notes) + "</ul>"
    return out


def _section_runs(h: UnitHistory) -> str:
    cls = {"passed": "pass", "failed": "fail", "incomplete": "warn"}
    rows = []
    for i, r in enumerate(h.runs, 1):
        verdict = verdict_text(r.verdict, r.mode) if r.verdict else r.status
        rows.append([i, r.started_utc.strftime("%Y-%m-%d %H:%M") if r.started_utc else "-", r.procedure, r.station or "-",
                     Cell(mode_word(r.mode), "" if r.evidence else "warn"),
                     Cell(verdict, cls.get(r.verdict or "", "") if r.evidence else "warn"), r.first_failed_check or "", r.operator])
    return table(["#", "start UTC", "procedure", "station", "mode", "verdict", "first failed check", "operator"], rows, left=8)


def _section_figure(h: UnitHistory, f: Figure) -> str:
    verdict_cls = "fail" if f.outlier else ("" if f.z is not None else "note")
    rows: list[list[Any]] = [
        ["latest compared", (fmt_quantity(f.latest.value, f.units) + ("" if f.latest.evidence else " (dry-run)")) if f.latest else "-"],
        ["across runs", fmt_range(min(p.value for p in f.points), max(p.value for p in f.points), f.units) + f" ({len(f.points)} values)"],
        ["lot median", fmt_quantity(f.lot_median, f.units) if f.lot_median is not None else "-"],
        ["lot spread (1.4826 MAD)", fmt_quantity(f.lot_spread, f.units) if f.lot_spread is not None else "-"],
        ["robust z", f"{f.z:+.2f}" if f.z is not None and f.z == f.z and abs(f.z) != float("inf") else ("inf" if f.z else "-")],
        ["against its lot", Cell(f.verdict, verdict_cls)],
    ]
    return figure_png(_figure(h, f), f"{f.name}: every value of {h.serial} by date (hollow: dry-run), and against the latest value "
                                     f"of each other unit of {h.part or 'its part number'} (band: median ± {OUTLIER_Z:g} robust spreads)") + \
        table(["item", "value"], rows, left=2) + table(
            ["start UTC", "check", "procedure", "mode", "value", "outcome"],
            [[p.when.strftime("%Y-%m-%d %H:%M") if p.when else "-", p.check, p.procedure, Cell(mode_word(p.mode), "" if p.evidence else "warn"),
              fmt_quantity(p.value, f.units), p.outcome] for p in f.points], left=4)


def _figure(h: UnitHistory, f: Figure) -> Any:
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 3.2), gridspec_kw={"width_ratios": [3, 2]})
    units = f" [{f.units}]" if f.units else ""
    dates = [p.when or datetime.min for p in f.points]
    real = [(d, p.value) for d, p in zip(dates, f.points) if p.evidence]
    dry = [(d, p.value) for d, p in zip(dates, f.points) if not p.evidence]
    if real:
        ax1.plot(*zip(*real), "o", color=REAL_COLOUR, label="real run")
    if dry:
        ax1.plot(*zip(*dry), "o", mfc="none", color=REAL_COLOUR, label="dry-run (not evidence)")
    if f.lot_median is not None:
        ax1.axhline(f.lot_median, color=LOT_COLOUR, ls="--", lw=1, label=f"lot median ({len(f.lot)} units)")
    ax1.set_xlabel("run start (UTC)")
    ax1.set_ylabel(f"{f.name}{units}")
    ax1.legend(fontsize=8, loc="best")
    fig.autofmt_xdate()
    serials = [v.serial for v in f.lot] + [h.serial]
    ys = list(range(len(serials)))
    for y, v in zip(ys, f.lot):
        ax2.plot(v.value, y, "o", color=LOT_COLOUR, mfc=LOT_COLOUR if v.evidence else "none")
    if f.latest is not None:
        ax2.plot(f.latest.value, ys[-1], "D", color=UNIT_COLOUR, mfc=UNIT_COLOUR if f.latest.evidence else "none", ms=8)
    if f.lot_median is not None:
        ax2.axvline(f.lot_median, color=LOT_COLOUR, ls="--", lw=1)
        if f.lot_spread:
            ax2.axvspan(f.lot_median - OUTLIER_Z * f.lot_spread, f.lot_median + OUTLIER_Z * f.lot_spread, color=LOT_COLOUR, alpha=0.12)
    ax2.set_yticks(ys, serials)
    ax2.set_xlabel(f"{f.name}{units}")
    ax2.set_title(f"{h.serial} among {h.part or 'its lot'}: {f.verdict.split(' (')[0].split(';')[0]}", fontsize=9)
    fig.tight_layout()
    return fig

"""Building blocks of self-contained HTML pages: figures inlined as PNG, tables, escaped text.

No external files, scripts or fonts: a report is one ``.html`` file a technician can attach to an
acceptance record and open anywhere.
"""

from __future__ import annotations

import base64
import html
import io
from dataclasses import dataclass
from typing import Any, Iterable

import matplotlib

matplotlib.use("Agg")  # no display on test benches' CI machines; must precede pyplot imports
import matplotlib.pyplot as plt  # noqa: E402

from bench.quantity_format import fmt_hms, fmt_number  # noqa: E402

STYLE = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:2em auto;max-width:1100px;color:#222}
h1{font-size:1.6em}h2{font-size:1.25em;border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:2em}
table{border-collapse:collapse;margin:.5em 0 1em 0;font-size:.92em}
th,td{border:1px solid #ccc;padding:.25em .6em;text-align:right}th{background:#f3f3f3}
td.l,th.l{text-align:left}.pass{color:#060;font-weight:600}.fail{color:#b00;font-weight:600}
.warn{color:#a60;font-weight:600}
.note{color:#555;font-size:.9em}.verdict{font-size:1.6em;margin:.3em 0}figure{margin:1em 0}figcaption{color:#555;font-size:.9em}
img{max-width:100%}
.banner{background:#ffd54f;border:3px solid #8a6d00;color:#3a2d00;font-size:1.35em;font-weight:700;padding:.5em .8em;margin:0 0 1em 0}
.watermark::before{content:attr(data-mode);position:fixed;top:40%;left:8%;font-size:9em;font-weight:800;color:rgba(160,120,0,.13);
transform:rotate(-24deg);pointer-events:none;z-index:0;white-space:nowrap}
"""


def esc(text: Any) -> str:
    """``text`` as HTML-escaped string."""
    return html.escape(str(text))


def figure_png(fig: "plt.Figure", caption: str = "", dpi: int = 110) -> str:
    """A matplotlib figure as an inline ``<figure>`` with a base64 PNG; closes the figure."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
    plt.close(fig)
    data = base64.b64encode(buf.getvalue()).decode("ascii")
    cap = f"<figcaption>{esc(caption)}</figcaption>" if caption else ""
    return f'<figure><img alt="{esc(caption)}" src="data:image/png;base64,{data}">{cap}</figure>'


def fmt(value: Any, digits: int = 4) -> str:
    """Numbers with ``digits`` significant digits (:func:`bench.quantity_format.fmt_number`, the one
    formatter of every view), everything else as text."""
    if isinstance(value, float):
        return fmt_number(value, digits)
    return "" if value is None else str(value)


def hms(seconds: float | None) -> str:
    """A run time or duration ``seconds`` (s) as ``H:MM:SS``, rounded to the second (the report's one
    presentation of run time); ``-`` for None or NaN."""
    return fmt_hms(seconds)


def table(headers: list[str], rows: Iterable[Iterable[Any]], title: str = "", left: int = 1) -> str:
    """An HTML table; the first ``left`` columns are left-aligned (names), the rest right (numbers)."""
    cls = lambda j: ' class="l"' if j < left else ""  # noqa: E731
    head = "".join(f"<th{cls(j)}>{esc(h)}</th>" for j, h in enumerate(headers))
    body = "".join("<tr>" + "".join(_td(c, j < left) for j, c in enumerate(r)) + "</tr>" for r in rows)
    t = f"<h3>{esc(title)}</h3>" if title else ""
    return f"{t}<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


@dataclass(frozen=True)
class Cell:
    """A :func:`table` cell with extra CSS classes, e.g. ``Cell("failed", "fail")`` (classes in
    :data:`STYLE`: ``pass``, ``fail``, ``warn``, ``note``); ``value`` is formatted with :func:`fmt`."""

    value: Any
    cls: str = ""


def _td(c: Any, left: bool) -> str:
    classes = (["l"] if left else []) + (c.cls.split() if isinstance(c, Cell) else [])
    attr = f' class="{esc(" ".join(classes))}"' if classes else ""
    return f"<td{attr}>{esc(fmt(c.value if isinstance(c, Cell) else c))}</td>"


def page(title: str, sections: Iterable[tuple[str, str]], subtitle: str = "", banner: str = "", watermark: str = "") -> str:
    """A whole HTML document: ``sections`` are (heading, inner HTML) pairs. ``banner``: a line above
    everything (a run that is not on real instruments: :func:`bench.run_mode.banner`), repeated at
    the end; ``watermark``: a word printed faintly across every screen and printed page."""
    parts = [f"<h2>{esc(h)}</h2>\n{body}" for h, body in sections]
    sub = f'<p class="note">{esc(subtitle)}</p>' if subtitle else ""
    top = f'<div class="banner" id="mode-banner">{esc(banner)}</div>' if banner else ""
    bottom = f'<div class="banner">{esc(banner)}</div>' if banner else ""
    body = f' class="watermark" data-mode="{esc(watermark)}"' if watermark else ""
    return (f"<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>{esc(title)}</title>"
            f"<style>{STYLE}</style></head><body{body}>{top}<h1>{esc(title)}</h1>{sub}\n" + "\n".join(parts) + f"{bottom}</body></html>\n")

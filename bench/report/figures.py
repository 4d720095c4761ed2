"""Figures of the run report (``bench report``): matplotlib (Agg) figures a technician can read on
paper: axis labels with units, titles, legends, grids, at most 1100 px wide.

Every function returns an open :class:`matplotlib.figure.Figure`; :func:`bench.report.html.figure_png`
turns it into an inline PNG and closes it. Long series are reduced before plotting
(:func:`envelope`: at most :data:`MAX_POINTS` points per line, keeping every bin's minimum and
maximum so spikes stay visible).

Units: run time in s, shown on the axes as H:MM:SS like everywhere in the report (:func:`time_axis`),
rates in deg/s, temperatures in °C, pressure in Torr, Allan deviation in deg/s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from matplotlib.ticker import FuncFormatter, MultipleLocator

from bench.report.html import hms, plt  # Agg backend selected there, before pyplot is imported

FIG_WIDTH_IN = 9.6
"""Figure width (inches); at the report's 110 dpi that is 1056 px, under the 1100 px page width."""
ROW_HEIGHT_IN = 3.1
"""Height of one row of subplots (inches)."""
MAX_POINTS = 5000
"""Most points drawn per line (min/max envelope) or per scatter (stride)."""
AXIS_COLORS = {"x": "tab:red", "y": "tab:green", "z": "tab:blue"}


@dataclass
class Series:
    """One line to plot: ``label``, times ``t`` (run time, s) and values ``y`` (units of the axes)."""

    label: str
    t: np.ndarray
    y: np.ndarray
    style: str = "-"


# ---- data reduction -----------------------------------------------------------------------------
def envelope(t: np.ndarray, y: np.ndarray, max_points: int = MAX_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """``(t, y)`` reduced to at most ``max_points`` points: the samples are cut into consecutive bins
    and each bin keeps its minimum and maximum, in time order, plus its first NaN if it has one (so
    gaps stay gaps). Series of ``max_points`` points or fewer come back unchanged."""
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    n = min(t.shape[0], y.shape[0])
    t, y = t[:n], y[:n]
    if n <= max_points or max_points < 3:
        return t, y
    k = math.ceil(n / (max_points // 3))  # samples per bin
    nb = math.ceil(n / k)  # bins; the padding (< k) never fills a whole bin
    pad = nb * k - n
    nan = np.isnan(y)
    lo = np.concatenate([np.where(nan, np.inf, y), np.full(pad, np.inf)]).reshape(nb, k)
    hi = np.concatenate([np.where(nan, -np.inf, y), np.full(pad, -np.inf)]).reshape(nb, k)
    gap = np.concatenate([nan, np.zeros(pad, dtype=bool)]).reshape(nb, k)
    base = np.arange(nb) * k
    imin = np.minimum(base + np.argmin(lo, axis=1), n - 1)
    imax = np.minimum(base + np.argmax(hi, axis=1), n - 1)
    inan = np.where(gap.any(axis=1), base + np.argmax(gap, axis=1), imin)
    idx = np.sort(np.stack([imin, imax, inan], axis=1), axis=1).ravel()
    return t[idx], y[idx]


def break_gaps(t: np.ndarray, y: np.ndarray, factor: float = 10.0) -> tuple[np.ndarray, np.ndarray]:
    """``(t, y)`` with a NaN row inserted in every time gap longer than ``factor`` × the median
    sample interval, so a line is not drawn across a stretch without data (sensor off)."""
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    if t.size < 3:
        return t, y
    dt = np.diff(t)
    med = float(np.median(dt))
    gaps = np.nonzero(dt > factor * med)[0] if med > 0 else np.zeros(0, dtype=np.int64)
    if gaps.size == 0:
        return t, y
    at = gaps + 1
    return np.insert(t, at, 0.5 * (t[gaps] + t[at])), np.insert(y, at, np.nan)


def decimate(n: int, max_points: int = MAX_POINTS) -> np.ndarray:
    """Indices of at most ``max_points`` evenly strided samples out of ``n`` (for scatter plots)."""
    if n <= max_points:
        return np.arange(n)
    return np.linspace(0, n - 1, max_points).astype(np.int64)


def binned_mean(x: np.ndarray, y: np.ndarray, bins: int = 60) -> tuple[np.ndarray, np.ndarray]:
    """Mean of ``y`` in ``bins`` equal-width bins of ``x``: (bin centres, means) of non-empty bins."""
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    ok = np.isfinite(x) & np.isfinite(y)
    x, y = x[ok], y[ok]
    if x.size == 0:
        return np.zeros(0), np.zeros(0)
    lo, hi = float(x.min()), float(x.max())
    if hi <= lo:
        return np.array([lo]), np.array([float(y.mean())])
    edges = np.linspace(lo, hi, bins + 1)
    counts, _ = np.histogram(x, edges)
    sums, _ = np.histogram(x, edges, weights=y)
    keep = counts > 0
    return (0.5 * (edges[:-1] + edges[1:]))[keep], sums[keep] / counts[keep]


TIME_LABEL = "run time (h:mm:ss)"
"""Label of every run-time axis."""
TIME_TICK_STEPS_S = (1, 2, 5, 10, 15, 30, 60, 120, 300, 600, 900, 1800, 3600, 7200, 10800, 21600, 43200, 86400)
"""Run-time tick spacings (s) that read well as H:MM:SS."""
MAX_TIME_TICKS = 8
"""Most run-time ticks on an axis."""


def time_axis(span_s: float) -> tuple[float, str]:
    """How to show run times spanning ``span_s`` seconds: (tick spacing in s, axis label). Ticks are
    the shortest spacing of :data:`TIME_TICK_STEPS_S` giving at most :data:`MAX_TIME_TICKS` ticks,
    labelled H:MM:SS."""
    for step in TIME_TICK_STEPS_S:
        if span_s / step <= MAX_TIME_TICKS:
            return float(step), TIME_LABEL
    return float(math.ceil(span_s / MAX_TIME_TICKS / 86400) * 86400), TIME_LABEL


def _set_time_axis(ax: Any, step_s: float) -> None:
    """Run-time ticks every ``step_s`` seconds, labelled H:MM:SS."""
    ax.xaxis.set_major_locator(MultipleLocator(step_s))
    ax.xaxis.set_major_formatter(FuncFormatter(lambda x, _pos: hms(x)))


def _span(series: Sequence[Series]) -> float:
    spans = [float(np.nanmax(s.t) - np.nanmin(s.t)) for s in series if np.size(s.t)]
    return max(spans) if spans else 0.0


def _finish(ax: Any, xlabel: str, ylabel: str, title: str = "", legend: bool = True) -> None:
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    if title:
        ax.set_title(title, fontsize=10)
    ax.grid(True, which="major", alpha=0.4)
    if legend and ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=8, loc="best", framealpha=0.85)


def _figure(nrows: int, ncols: int = 1, height_in: float | None = None, **kw: Any) -> tuple[Any, np.ndarray]:
    fig, axes = plt.subplots(nrows, ncols, figsize=(FIG_WIDTH_IN, height_in or ROW_HEIGHT_IN * nrows), squeeze=False, **kw)
    return fig, axes


def _plot_series(ax: Any, series: Sequence[Series], step_s: float) -> None:
    """Lines of ``series`` against run time, ticks every ``step_s`` seconds (H:MM:SS)."""
    for s in series:
        t, y = envelope(s.t, s.y)
        ax.plot(t, y, s.style, lw=1.0, label=s.label)
    _set_time_axis(ax, step_s)


# ---- time series ----------------------------------------------------------------------------------
def fig_environment(temperatures: Sequence[Series], pressure: Series | None, title: str = "Temperature and pressure") -> Any:
    """Temperatures (°C) vs run time and, below, pressure (Torr, log axis) when given."""
    rows = (1 if temperatures else 0) + (1 if pressure is not None else 0)
    if rows == 0:
        raise ValueError("nothing to plot")
    step, xlabel = time_axis(_span([*temperatures, *([pressure] if pressure else [])]))
    fig, axes = _figure(rows, sharex=True)
    r = 0
    if temperatures:
        ax = axes[r, 0]
        _plot_series(ax, temperatures, step)
        _finish(ax, xlabel if rows == 1 else "", "temperature (°C)", title)
        r += 1
    if pressure is not None:
        ax = axes[r, 0]
        ok = np.isfinite(pressure.y) & (pressure.y > 0)
        _plot_series(ax, [Series(pressure.label, pressure.t[ok], pressure.y[ok])], step)
        ax.set_yscale("log")
        _finish(ax, xlabel, "pressure (Torr)", "" if temperatures else title)
    fig.tight_layout()
    return fig


def fig_rates(gyro: Sequence[Series], reference: Sequence[Series], title: str = "Angular rates") -> Any:
    """Gyro outputs (deg/s) vs run time and, below, the table or bench rate (deg/s) when recorded."""
    rows = (1 if gyro else 0) + (1 if reference else 0)
    if rows == 0:
        raise ValueError("nothing to plot")
    step, xlabel = time_axis(_span([*gyro, *reference]))
    fig, axes = _figure(rows, sharex=True)
    r = 0
    if gyro:
        _plot_series(axes[r, 0], gyro, step)
        _finish(axes[r, 0], xlabel if rows == 1 else "", "gyro output (deg/s)", f"{title}: sensor outputs")
        r += 1
    if reference:
        _plot_series(axes[r, 0], reference, step)
        _finish(axes[r, 0], xlabel, "rate (deg/s)", "Reference motion (table / bench)")
    fig.tight_layout()
    return fig


def fig_series(series: Sequence[Series], title: str) -> Any:
    """Each series (label ``name (units)``) on its own axis vs run time: an instrument's readings as
    its kind declares them (``Kind.figures``)."""
    if not series:
        raise ValueError("nothing to plot")
    step, xlabel = time_axis(_span(series))
    fig, axes = _figure(len(series), sharex=True)
    for r, s in enumerate(series):
        _plot_series(axes[r, 0], [s], step)
        _finish(axes[r, 0], xlabel if r == len(series) - 1 else "", s.label, title if r == 0 else "", legend=False)
    fig.tight_layout()
    return fig


# ---- thermal calibration --------------------------------------------------------------------------
def _poly(c: Sequence[float], x: np.ndarray) -> np.ndarray:
    """Polynomial with ascending coefficients ``c`` at ``x``."""
    return np.polynomial.polynomial.polyval(np.asarray(x, dtype=float), np.asarray(c, dtype=float))


def fig_thermal(axes_json: dict[str, dict[str, Any]], temp_c: np.ndarray | None, gyro: dict[str, np.ndarray],
                fitted: np.ndarray | None = None) -> Any:
    """Per gyro axis: zero-rate samples of the output (deg/s) vs temperature (°C) with the fitted
    bias polynomial (ascending ``poly_degc``, drawn over the fit's ``temp_range_c`` when given), and
    below, the residuals (deg/s) of the fitted samples.

    ``temp_c`` and ``gyro[axis]`` are the zero-rate samples (equal length); ``fitted`` marks those
    the fit used (others, e.g. the warm-up, are drawn grey); without samples only the polynomial is
    drawn (over ``temp_range_c``, else -40..85 °C)."""
    names = list(axes_json)
    if not names:
        raise ValueError("no axes in the thermal calibration")
    fig, axes = _figure(2, len(names), height_in=5.6, gridspec_kw={"height_ratios": [2, 1]}, sharex="col")
    for j, a in enumerate(names):
        info = axes_json[a]
        c = [float(v) for v in info["poly_degc"]]
        top, bot = axes[0, j], axes[1, j]
        color = AXIS_COLORS.get(a, "tab:blue")
        y = gyro.get(a)
        x = yy = np.zeros(0)
        use = np.zeros(0, dtype=bool)
        if temp_c is not None and y is not None:
            x = np.asarray(temp_c, dtype=float)
            yy = np.asarray(y, dtype=float)
            use = np.ones(x.size, dtype=bool) if fitted is None else np.asarray(fitted, dtype=bool)
            ok = np.isfinite(x) & np.isfinite(yy)
            x, yy, use = x[ok], yy[ok], use[ok]
        rng = info.get("temp_range_c")
        if rng and len(rng) == 2 and all(isinstance(v, (int, float)) for v in rng):
            lo, hi = float(rng[0]), float(rng[1])
        elif use.any():
            lo, hi = float(x[use].min()), float(x[use].max())
        else:
            lo, hi = -40.0, 85.0
        if (~use).any():
            idx = decimate(int((~use).sum()))
            top.plot(x[~use][idx], yy[~use][idx], ".", ms=1.5, alpha=0.3, color="0.6", label="not fitted (warm-up)")
        if use.any():
            xf, yf = x[use], yy[use]
            idx = decimate(xf.size)
            top.plot(xf[idx], yf[idx], ".", ms=1.5, alpha=0.25, color=color, label="zero-rate samples")
            bx, by = binned_mean(xf, yf)
            top.plot(bx, by, "o", ms=3, color="k", label="bin means")
            res = yf - _poly(c, xf)
            bot.plot(xf[idx], res[idx], ".", ms=1.5, alpha=0.25, color=color)
            rx, ry = binned_mean(xf, res)
            bot.plot(rx, ry, "o", ms=3, color="k")
        grid = np.linspace(lo, hi, 200)
        top.plot(grid, _poly(c, grid), "-", color="k", lw=1.5, label=f"fit (degree {len(c) - 1})")
        bot.axhline(0.0, color="k", lw=0.8)
        rms = info.get("residual_rms_dps")
        _finish(top, "", "bias (deg/s)", f"gyro {a}: bias vs temperature", legend=j == 0)
        _finish(bot, "temperature (°C)", "residual (deg/s)",
                f"residuals, RMS {rms:.3g} deg/s" if isinstance(rms, (int, float)) and math.isfinite(rms) else "residuals",
                legend=False)
    fig.tight_layout()
    return fig


# ---- rate transfer --------------------------------------------------------------------------------
def fig_rate_transfer(axes_json: dict[str, dict[str, Any]]) -> Any:
    """Per gyro axis (columns): mean output (deg/s) vs commanded rate (deg/s) with the fitted line
    (1 + scale-factor error)·rate + bias; below, percent error vs |rate| (log axis), one row for the
    error against the zero-rate reference (``percent_error_ref``) and one for the raw error
    (``percent_error``, bias included), each when present (+ rates filled, − rates open)."""
    names = [a for a in axes_json if axes_json[a].get("steps")]
    if not names:
        raise ValueError("no rate steps in the rate-transfer result")
    kinds = [(key, title) for key, title in (("percent_error_ref", "error vs zero-rate ref."),
                                            ("percent_error", "raw error (with bias)"))
             if any(math.isfinite(_num(s.get(key))) for a in names for s in axes_json[a]["steps"])]
    fig, axes = _figure(1 + len(kinds), len(names), height_in=2.9 * (1 + len(kinds)))
    for j, a in enumerate(names):
        info = axes_json[a]
        steps = info["steps"]
        rate = np.array([_num(s["rate_dps"]) for s in steps])
        out = np.array([_num(s["mean_output_dps"]) for s in steps])
        color = AXIS_COLORS.get(a, "tab:blue")
        top = axes[0, j]
        top.plot(rate, out, "o", ms=4, color=color, label="mean output")
        sfe, bias = _num(info.get("scale_factor_error")), _num(info.get("bias_dps"))
        if math.isfinite(sfe) and math.isfinite(bias) and np.isfinite(rate).any():
            g = np.linspace(np.nanmin(rate), np.nanmax(rate), 50)
            top.plot(g, (1 + sfe) * g + bias, "-", color="k", lw=1,
                     label=f"fit: SF error {100 * sfe:+.3g} %\nbias {bias:+.3g} deg/s")
        _finish(top, "commanded rate (deg/s)", "mean output (deg/s)", f"gyro {a}: input / output", legend=False)
        top.legend(fontsize=8, loc="lower right", framealpha=0.85)
        for r, (key, title) in enumerate(kinds, start=1):
            ax = axes[r, j]
            pe = np.array([_num(s.get(key)) for s in steps])
            for sign, fill, word in ((1, color, "+"), (-1, "none", "−")):
                sel = np.isfinite(pe) & np.isfinite(rate) & (np.sign(rate) == sign)
                if sel.any():
                    ax.plot(np.abs(rate[sel]), pe[sel], "o", ms=5, color=color, mfc=fill, label=f"{word} rates")
            if np.any(np.isfinite(pe) & (np.abs(rate) > 0)):
                ax.set_xscale("log")
            ax.axhline(0.0, color="k", lw=0.8)
            _finish(ax, "|commanded rate| (deg/s)", "output error (%)", f"gyro {a}: {title}", legend=j == 0)
    fig.tight_layout()
    return fig


def _num(v: Any) -> float:
    """``v`` as float; None and non-numbers are NaN."""
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


# ---- Allan deviation ------------------------------------------------------------------------------
SQRT_H_IN_SQRT_S = 60.0
"""√(1 h) in √s: an ARW of N deg/√h is N/60 deg/√s."""
BI_FLOOR = math.sqrt(2 * math.log(2) / math.pi)
"""Allan-deviation floor / bias instability (≈ 0.664, IEEE Std 952)."""


def fig_allan(axes_json: dict[str, dict[str, Any]]) -> Any:
    """Per gyro axis: Allan deviation (deg/s) vs cluster time τ (s), log-log, with its confidence
    band when given and the noise-term lines: ARW slope −1/2 (σ = N/√τ), bias instability
    slope 0 (σ = 0.664·B) and RRW slope +1/2 (σ = K·√(τ/3)), each drawn from the fitted coefficient."""
    names = [a for a in axes_json if axes_json[a].get("taus_s")]
    if not names:
        raise ValueError("no Allan deviation in the noise result")
    ncols = min(len(names), 3)
    nrows = math.ceil(len(names) / ncols)
    fig, axes = _figure(nrows, ncols, height_in=4.4 * nrows)
    for j, a in enumerate(names):
        ax = axes[j // ncols, j % ncols]
        info = axes_json[a]
        tau = np.asarray([_num(v) for v in info["taus_s"]])
        adev = np.asarray([_num(v) for v in info["adev_dps"]])
        ok = np.isfinite(tau) & np.isfinite(adev) & (tau > 0) & (adev > 0)
        color = AXIS_COLORS.get(a, "tab:blue")
        lo_hi = (info.get("adev_lo_dps"), info.get("adev_hi_dps"))
        if lo_hi[0] is not None and lo_hi[1] is not None:
            lo = np.asarray([_num(v) for v in lo_hi[0]])
            hi = np.asarray([_num(v) for v in lo_hi[1]])
            band = ok & np.isfinite(lo) & np.isfinite(hi) & (lo > 0)
            if band.any():
                ax.fill_between(tau[band], lo[band], hi[band], color=color, alpha=0.2, lw=0, label="confidence band")
        ax.loglog(tau[ok], adev[ok], "-", color=color, lw=1.5, label="Allan deviation")
        if ok.any():
            g = np.geomspace(tau[ok].min(), tau[ok].max(), 50)
            arw = _num(info.get("arw_deg_per_sqrt_h"))
            bi = _num(info.get("bias_instability_deg_per_h"))
            rrw = _num(info.get("rrw_deg_per_h_per_sqrt_h"))
            ymin, ymax = adev[ok].min() / 3, adev[ok].max() * 3
            if math.isfinite(arw) and arw > 0:
                ax.loglog(g, arw / SQRT_H_IN_SQRT_S / np.sqrt(g), "--", color="0.3", lw=1, label=f"ARW −½: {arw:.3g} deg/√h")
            if math.isfinite(bi) and bi > 0:
                ax.loglog(g, np.full_like(g, BI_FLOOR * bi / 3600.0), ":", color="0.3", lw=1.3, label=f"BI 0: {bi:.3g} deg/h")
            if math.isfinite(rrw) and rrw > 0:
                ax.loglog(g, rrw / 3600.0 ** 1.5 * np.sqrt(g / 3.0), "-.", color="0.3", lw=1, label=f"RRW +½: {rrw:.3g} deg/h/√h")
            ax.set_ylim(ymin, ymax)
        ax.grid(True, which="minor", alpha=0.15)
        _finish(ax, "cluster time τ (s)", "Allan deviation (deg/s)", f"gyro {a}")
    for j in range(len(names), nrows * ncols):
        axes[j // ncols, j % ncols].set_visible(False)
    fig.tight_layout()
    return fig


# ---- pre/post comparison --------------------------------------------------------------------------
@dataclass
class StagePoint:
    """One check result in a pre/post comparison: ``stage`` label, ``value`` in display units,
    ``outcome`` (passed/failed) of the comparison (``None`` for the reference itself)."""

    stage: str
    value: float
    outcome: str | None = None


def fig_pre_post(panels: dict[str, tuple[str, dict[str, list[StagePoint]]]]) -> Any:
    """One subplot per statistic: ``panels[statistic] = (y label with units, {signal: points})``;
    each signal is a line over the stages in order, failed comparisons circled in red."""
    if not panels:
        raise ValueError("nothing to compare")
    fig, axes = _figure(len(panels), height_in=3.0 * len(panels))
    for r, (stat, (ylabel, lines)) in enumerate(panels.items()):
        ax = axes[r, 0]
        stages: list[str] = []
        for pts in lines.values():
            for p in pts:
                if p.stage not in stages:
                    stages.append(p.stage)
        pos = {s: i for i, s in enumerate(stages)}
        for sig, pts in lines.items():
            axis = sig.rsplit(".", 1)[-1]
            x = [pos[p.stage] for p in pts]
            ax.plot(x, [p.value for p in pts], "o-", color=AXIS_COLORS.get(axis), label=sig)
            bad = [(pos[p.stage], p.value) for p in pts if p.outcome == "failed"]
            if bad:
                ax.plot(*zip(*bad), "o", ms=12, mfc="none", mec="tab:red", mew=1.5)
        if any(p.outcome == "failed" for pts in lines.values() for p in pts):
            ax.plot([], [], "o", ms=10, mfc="none", mec="tab:red", label="change out of tolerance")
        ax.set_xticks(range(len(stages)))
        ax.set_xticklabels(stages, fontsize=8)
        _finish(ax, "stage", ylabel, f"{stat.replace('_', ' ')} per stage")
    fig.tight_layout()
    return fig


def fig_stage_errors(panels: dict[str, dict[str, tuple[np.ndarray, np.ndarray]]]) -> Any:
    """Per signal: output error (%) vs |commanded rate| (deg/s, log axis) of every recording window,
    one marker per stage (``panels[signal][stage] = (rates, percent errors)``), + rates filled,
    − rates open; stages are offset slightly along the rate axis so they do not hide each other."""
    if not panels:
        raise ValueError("nothing to plot")
    ncols = min(len(panels), 3)
    nrows = math.ceil(len(panels) / ncols)
    fig, axes = _figure(nrows, ncols, height_in=3.8 * nrows)
    markers = "osD^v<>p"
    for j, (sig, stages) in enumerate(panels.items()):
        ax = axes[j // ncols, j % ncols]
        n = len(stages)
        for k, (stage, (rate, pe)) in enumerate(stages.items()):
            rate = np.asarray(rate, dtype=float)
            pe = np.asarray(pe, dtype=float)
            shift = 10 ** (0.03 * (k - (n - 1) / 2))  # a few % along the log axis
            color = f"C{k % 10}"
            m = markers[k % len(markers)]
            for sign, fill in ((1, color), (-1, "none")):
                sel = np.sign(rate) == sign
                if sel.any():
                    ax.plot(np.abs(rate[sel]) * shift, pe[sel], m, ms=5, color=color, mfc=fill,
                            label=stage if sign == 1 or not (np.sign(rate) == 1).any() else None)
        if any(np.any(np.abs(np.asarray(r)) > 0) for r, _ in stages.values()):
            ax.set_xscale("log")
        ax.axhline(0.0, color="k", lw=0.8)
        _finish(ax, "|commanded rate| (deg/s)", "output error (%)", sig)
    for j in range(len(panels), nrows * ncols):
        axes[j // ncols, j % ncols].set_visible(False)
    fig.tight_layout()
    return fig

"""HTML report of ``bench diagnose --report``: one self-contained page (``bench/report/html.py``)
with the residuals before and after, their spectra in time and table angle, covariate
correlations, Allan deviations, the evidence for each finding and the candidate table."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from bench.analysis.dataset import Dataset
from bench.analysis.diagnose.data import Prepared
from bench.analysis.diagnose.engine import GAIN_MIN, IC_MIN, Search, block_means
from bench.analysis.diagnose.result import DiagnoseResult
from bench.analysis.diagnose.structure import analyse, covariates
from bench.errors import InputError
from bench.report.html import esc, figure_png, page, plt, table

MAX_POINTS = 4000


def _decimate(t: np.ndarray, *ys: np.ndarray) -> tuple[np.ndarray, ...]:
    step = max(1, t.shape[0] // MAX_POINTS)
    return (t[::step], *(y[::step] for y in ys))


def _smooth(y: np.ndarray, w: int) -> np.ndarray:
    w = max(int(w), 1)
    if w == 1:
        return y
    k = np.ones(w) / w
    return np.convolve(np.pad(y, (w // 2, w - 1 - w // 2), mode="edge"), k, mode="valid")


def _binned(x: np.ndarray, y: np.ndarray, bins: int = 40) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = float(np.min(x)), float(np.max(x))
    if hi <= lo:
        return np.array([lo]), np.array([float(np.mean(y))])
    edges = np.linspace(lo, hi, bins + 1)
    idx = np.clip(np.digitize(x, edges) - 1, 0, bins - 1)
    cnt = np.bincount(idx, minlength=bins)
    s = np.bincount(idx, weights=y, minlength=bins)
    ok = cnt > 0
    return 0.5 * (edges[:-1] + edges[1:])[ok], s[ok] / cnt[ok]


def _evidence_axis(p: Prepared, effect: str, axis: str, nl: dict[str, Any]) -> tuple[str, np.ndarray, None]:
    """(label, x, None) of the covariate that shows a finding best."""
    if effect == "warmup_transient" and p.power_on is not None:
        return "time since power-on (s)", p.power_on, None
    if effect == "pressure_bias" and p.pressure is not None:
        return "log10 pressure (Torr)", np.log10(p.pressure), None
    if effect == "thermal_lag" and p.temp is not None:
        return "dT/dt (°C/s)", p.dtemp(), None
    if effect == "hysteresis" and p.temp is not None:
        return "temperature (°C)", p.temp, None
    if effect == "gear_eccentricity" and p.angle is not None:
        n = int(nl.get("harmonic", 1))
        return f"N·θ mod 360 (deg), N = {n}", np.mod(n * p.angle, 360.0), None
    if effect in ("scale_factor_asymmetry",) and p.ref is not None:
        return "reference rate (deg/s)", p.ref_axis(axis), None
    if effect == "scale_factor_tempco" and p.ref is not None and p.temp is not None:
        return "rate × (T − 25 °C) (deg/s·°C)", p.ref_axis(axis) * (p.temp - 25.0), None
    if effect == "time_skew" and p.ref is not None:
        return "rate derivative (deg/s²)", np.gradient(p.ref_axis(axis), p.t), None
    return "time (s)", p.t, None


def write_report(result: DiagnoseResult, ds: Dataset, path: str | Path) -> Path:
    """Write the report of ``result`` (for data ``ds``) to ``path``; returns the path."""
    internal = result._internal
    if internal is None:
        from bench.analysis.diagnose import diagnose

        internal = diagnose(ds, result.model_path)._internal
    p, s = internal
    out = Path(path)
    try:
        html = _render(result, p, s)
        out.write_text(html, encoding="utf-8")
    except OSError as exc:
        raise InputError(f"{out}: cannot write the report: {exc}") from None
    return out


def _render(result: DiagnoseResult, p: Prepared, s: Search) -> str:
    sections: list[tuple[str, str]] = []
    res_b = {a: s.baseline.axes[a].heldout_resid(p.blocks) for a in p.axes}
    res_e = {a: s.final.axes[a].heldout_resid(p.blocks) for a in p.axes}
    floor = result.noise_floor
    if result.structure:
        st_b, st_e = result.structure["baseline"], result.structure["extended"]
    else:
        st_b = {a: analyse(p, a, res_b[a], floor[a]) for a in p.axes}
        st_e = {a: analyse(p, a, res_e[a], floor[a]) for a in p.axes}

    # summary
    lines = "".join(f"<li>{esc(line)}</li>" for line in result.summary_lines())
    rows = [[a, v["rms_baseline"], v["rms_extended"], floor[a], v["rms_baseline"] / v["rms_extended"]]
            for a, v in result.axes.items()]
    sections.append(("Summary", f"<ul>{lines}</ul>" + table(
        ["axis", "baseline held-out RMS (deg/s)", "extended held-out RMS (deg/s)", "noise floor (deg/s)", "ratio"], rows)
        + f'<p class="note">{result.rows} rows at {result.sample_rate_hz:.4g} Hz from {esc(result.source)}; '
          f"{p.blocks.count} contiguous blocks of {p.blocks.length / p.fs:.4g} s dealt to {p.blocks.folds} folds. "
          f"Acceptance: ΔIC &lt; −{IC_MIN:g} (effective-rows information criterion on held-out error) and held-out "
          f"RMS gain ≥ {100 * GAIN_MIN:g} % per sample or on the {result.band_s:.4g}-s block means (consistent over "
          f"blocks), then the open-world checks (docs/diagnose.md, Method 6).</p>"))

    # findings
    if result.findings:
        frows = []
        for f in result.findings:
            ev = f.evidence
            frows.append([f.effect, f.axis, _fmt_params(f.params), f.rms_before, f.rms_after, f.gain, f.gain_band,
                          ev.get("d_ic", float("nan")), ev.get("phi", float("nan")), ev.get("t", float("nan"))])
        body = table(["effect", "axis", "parameters", "RMS before", "RMS after", "gain", "gain on block means", "ΔIC",
                      "φ", "t"], frows, left=3)
        for (term, before, after), f in zip(s.sequence, result.findings):
            axes = term.built.axes
            fig, axs = plt.subplots(1, len(axes), figsize=(5.2 * len(axes), 3.4), squeeze=False)
            for ax, a in zip(axs[0], axes):
                rb = before.axes[a].heldout_resid(p.blocks)
                ra = after.axes[a].heldout_resid(p.blocks)
                label, x, _ = _evidence_axis(p, term.effect, a, term.nl)
                y_b, y_c = rb, rb - ra
                if term.effect == "gear_eccentricity":
                    w = p.ref_axis(a)
                    sel = np.abs(w) > 0.5
                    x, y_b, y_c = x[sel], (rb / np.where(w == 0, 1, w))[sel], ((rb - ra) / np.where(w == 0, 1, w))[sel]
                    ax.set_ylabel("residual / rate")
                else:
                    ax.set_ylabel("deg/s")
                bx, by = _binned(x, y_b)
                cx, cy = _binned(x, y_c)
                ax.plot(bx, by, "o", ms=3, label="residual without the term (binned)")
                ax.plot(cx, cy, "-", lw=1.5, label="fitted term")
                ax.set_xlabel(label)
                ax.set_title(f"{term.effect} on {a}")
                ax.grid(alpha=0.3)
                ax.legend(fontsize=7)
            body += figure_png(fig, f"Evidence for {f.effect} ({f.axis}): {f.describe()}; held-out RMS "
                                    f"{f.rms_before:.3g} → {f.rms_after:.3g} deg/s ({f.gain:.2f}x)")
        sections.append(("Findings", body))
    else:
        sections.append(("Findings", "<p>No missing effect: no candidate passed the selection rule.</p>"))

    # the sensor's noise model
    if result.noise:
        nrows = []
        for a, sec in result.noise.items():
            ro = sec.get("ieee952") or {}
            nrows.append([a, sec["describe"], "yes" if sec["whitened"] else "no",
                          ro.get("arw_deg_per_sqrt_h"), ro.get("bias_instability_deg_per_h"),
                          ro.get("rrw_deg_per_h_per_sqrt_h")])
        body = ("<p>The sensor's stochastic model fitted per axis from what the selection leaves (Whittle "
                "likelihood: white, flicker, random walk, Gauss-Markov); where it is not white the fits were "
                "made against it (prewhitened). The IEEE 952 read-outs are those of the residual's Allan "
                "deviation.</p>"
                + "".join(f"<p>{esc(line)}</p>" for a in result.noise if (line := result.noise_line(a)))
                + table(["axis", "noise model", "fits against it", "ARW (deg/√h)", "B (deg/h)", "K (deg/h/√h)"],
                        nrows, left=2))
        sections.append(("Noise model", body))

    # unexplained structure
    if result.unexplained:
        urows = []
        for u in result.unexplained:
            for w in u["where"]:
                urows.append([u["axis"], w["against"] + (f" ({w['frequency_hz']:.4g} Hz)" if "frequency_hz" in w else ""),
                              w["rms_dps"], w["band_rms_dps"], w["d_ic"]])
        body = ("<p>Structure left after selection that no vocabulary term names: a generic probe (a smooth "
                "function of the covariate named) explains held-out data by the candidates' own rule. The engine "
                "says so rather than give a weak name.</p>"
                + "".join(f"<p>{esc(result.unexplained_line(u))}</p>" for u in result.unexplained)
                + table(["axis", "lives against", "size per sample (deg/s)", f"size on {result.band_s:.4g}-s means (deg/s)",
                         "ΔIC"], urows, left=2))
        fig, axs = plt.subplots(len(result.unexplained), 1, figsize=(10, 2.6 * len(result.unexplained)), squeeze=False)
        for ax, u in zip(axs[:, 0], result.unexplained):
            a = u["axis"]
            m = block_means(p.blocks.shaped(res_e[a])[:, :, 0].sum(axis=1), p.blocks)
            tb = block_means(p.blocks.shaped(p.t)[:, :, 0].sum(axis=1), p.blocks)
            ax.plot(tb, m, ".-", ms=3, lw=0.8)
            ax.set_ylabel(f"{a} block mean (deg/s)")
            ax.set_xlabel("time (s)")
            ax.grid(alpha=0.3)
        body += figure_png(fig, "Held-out residual of the extended model, block means, on the axes with unexplained structure")
        sections.append(("Unexplained", body))
    else:
        sections.append(("Unexplained", "<p>Nothing left: no generic probe finds structure in the residual of the "
                                        "extended model.</p>"))

    # residuals before/after
    fig, axs = plt.subplots(len(p.axes), 1, figsize=(10, 2.6 * len(p.axes)), sharex=True, squeeze=False)
    w = max(int(60 * p.fs), 1)
    for ax, a in zip(axs[:, 0], p.axes):
        t, rb, re_ = _decimate(p.t, res_b[a], res_e[a])
        ax.plot(t, rb, ",", color="tab:red", alpha=0.4)
        ax.plot(t, re_, ",", color="tab:blue", alpha=0.4)
        tt, sb, se = _decimate(p.t, _smooth(res_b[a], w), _smooth(res_e[a], w))
        ax.plot(tt, sb, color="tab:red", lw=1.2, label="baseline (60 s mean)")
        ax.plot(tt, se, color="tab:blue", lw=1.2, label="extended (60 s mean)")
        ax.set_ylabel(f"{a} residual (deg/s)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper right")
    axs[-1, 0].set_xlabel("time (s)")
    sections.append(("Held-out residuals", figure_png(fig, "Held-out residuals of the baseline (red) and the extended model (blue)")))

    # spectra
    fig, axs = plt.subplots(1, len(p.axes), figsize=(5 * len(p.axes), 3.4), squeeze=False)
    for ax, a in zip(axs[0], p.axes):
        ax.loglog(st_b[a]["psd_f"], st_b[a]["psd"], color="tab:red", lw=0.8, label="baseline")
        ax.loglog(st_e[a]["psd_f"], st_e[a]["psd"], color="tab:blue", lw=0.8, label="extended")
        ax.axhline(2 * floor[a] ** 2 / p.fs, color="k", ls="--", lw=0.8, label="white noise floor")
        ax.set_xlabel("frequency (Hz)")
        ax.set_ylabel(f"{a} PSD ((deg/s)²/Hz)")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7)
    body = figure_png(fig, "Power spectral density of the held-out residuals")
    ang = [a for a in p.axes if "angle_spectrum" in st_b[a]]
    if ang:
        fig, axs = plt.subplots(1, len(ang), figsize=(5 * len(ang), 3.2), squeeze=False)
        for ax, a in zip(axs[0], ang):
            n = np.arange(1, st_b[a]["angle_spectrum"].size + 1)
            ax.semilogy(n, st_b[a]["angle_spectrum"], color="tab:red", lw=0.8, label="baseline")
            ax.semilogy(n, st_e[a]["angle_spectrum"], color="tab:blue", lw=0.8, label="extended")
            ax.set_xlabel("harmonic N of the table angle")
            ax.set_ylabel(f"{a}: amplitude (fraction of rate)")
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7)
        body += figure_png(fig, "Spectrum in table angle: residual component ε·sin(Nθ+φ)·ω per harmonic")
    sections.append(("Spectra", body))

    # correlations
    names = list(covariates(p, p.axes[0]))
    crow = []
    for nm in names:
        row: list[Any] = [nm]
        for a in p.axes:
            row += [st_b[a]["correlations"].get(nm, float("nan")), st_e[a]["correlations"].get(nm, float("nan"))]
        crow.append(row)
    hdr = ["covariate"] + [f"{a} {k}" for a in p.axes for k in ("baseline", "extended")]
    sections.append(("Correlation with covariates", table(hdr, crow)
                     + '<p class="note">Pearson correlation of the held-out residual with each covariate.</p>'))

    # Allan deviation
    fig, axs = plt.subplots(1, len(p.axes), figsize=(5 * len(p.axes), 3.4), squeeze=False)
    for ax, a in zip(axs[0], p.axes):
        ax.loglog(st_b[a]["allan_tau_s"], st_b[a]["allan_dev"], "o-", ms=3, color="tab:red", label="baseline")
        ax.loglog(st_e[a]["allan_tau_s"], st_e[a]["allan_dev"], "o-", ms=3, color="tab:blue", label="extended")
        ax.loglog(st_e[a]["allan_tau_s"], st_e[a]["allan_white"], "k--", lw=0.8, label="white noise")
        ax.set_xlabel("cluster time τ (s)")
        ax.set_ylabel(f"{a} Allan deviation (deg/s)")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7)
    arow = [[a, st_b[a]["allan_ratio_max"], st_e[a]["allan_ratio_max"]] for a in p.axes]
    sections.append(("Allan deviation", figure_png(fig, "Allan deviation of the held-out residuals against white noise")
                     + table(["axis", "baseline ADEV / white at longest τ", "extended"], arow)))

    # candidates
    body = ""
    for i, rd in enumerate(result.rounds):
        rows = [[r["effect"], r["axis"], r["d_ic"], r["gain"], r["phi"], r["t"], "yes" if r["acceptable"] else "",
                 _fmt_params(r["nl"])] for r in rd]
        body += table(["effect", "axis", "ΔIC", "gain", "φ", "t", "acceptable", "nonlinear"], rows,
                      title=f"Round {i + 1}", left=2)
    if result.dropped:
        body += table(["effect", "axis", "why"], [[d["effect"], d["axis"], d.get("reason", "")] for d in result.dropped],
                      title="Dropped (backward elimination and open-world checks)", left=3)
    sections.append(("Candidates", body))

    extra = ""
    if result.skipped:
        extra += table(["skipped term", "absent"], [[k, ", ".join(result.skipped_reasons.get(k, []))] for k in result.skipped], left=2)
    if result.not_excited:
        extra += table(["term:axis", "not excited because"], [[k, v] for k, v in result.not_excited.items()], left=2)
    if result.fixed_terms:
        extra += "<p>Terms from the sensor model in the baseline: " + esc(", ".join(result.fixed_terms)) + "</p>"
    if extra:
        sections.append(("Skipped and known terms", extra))
    return page(f"bench diagnose: {Path(result.source).name}", sections,
                subtitle="What the sensor model gets wrong, the named cause, and the gain from extending the model.")


def _fmt_params(params: dict[str, Any]) -> str:
    out = []
    for k, v in params.items():
        if isinstance(v, float):
            out.append(f"{k}={v:.4g}")
        elif isinstance(v, list):
            out.append(f"{k}=[" + ", ".join(f"{x:.3g}" if isinstance(x, float) else str(x) for x in v) + "]")
        else:
            out.append(f"{k}={v}")
    return ", ".join(out)

"""What ``bench diagnose`` reports: per-axis held-out RMS, findings, skipped candidates, the
human summary and the extended sensor model."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bench.analysis.diagnose.confounded import line as in_time_line
from bench.analysis.diagnose.terms import CANDIDATES

SCHEMA = "bench-sensor-model/1"
UNBOUNDED = "τ not bounded by the data"
"""The start of a ``dropped`` reason for a warm-up whose τ interval reaches the top of its grid
(:func:`bench.analysis.diagnose._unbounded_warmup`); such a warm-up is said in the summary."""


@dataclass
class Finding:
    """A missing effect: vocabulary ``effect`` on ``axis`` (x, y, z or all) with its physical
    ``params``; held-out RMS (deg/s) before and after adding it, and their ratio ``gain``."""

    effect: str
    axis: str
    params: dict[str, Any]
    rms_before: float
    rms_after: float
    evidence: dict[str, Any] = field(default_factory=dict)

    @property
    def gain(self) -> float:
        return self.rms_before / self.rms_after if self.rms_after > 0 else float("inf")

    @property
    def gain_band(self) -> float:
        """Ratio of the held-out block-mean RMS before/after (the band slow effects live in)."""
        g = self.evidence.get("gain_band")
        if g is None:
            return float("nan")
        return 1.0 / (1.0 - g) if g < 1 else float("inf")

    def as_json(self) -> dict[str, Any]:
        return {"effect": self.effect, "axis": self.axis, "params": self.params,
                "rms_before": self.rms_before, "rms_after": self.rms_after, "gain": self.gain,
                "gain_band": _num(self.gain_band), "evidence": _plain(_evidence(self.evidence))}

    def as_effect(self) -> dict[str, Any]:
        """The entry of a sensor model's ``effects:`` list."""
        return {"effect": self.effect, "axis": self.axis, "params": dict(self.params),
                "source": f"bench diagnose: held-out RMS {self.rms_before:.3g} -> {self.rms_after:.3g} deg/s"}

    def describe(self) -> str:
        return CANDIDATES[self.effect].describe(self.params)


@dataclass
class DiagnoseResult:
    """Result of :func:`bench.analysis.diagnose.diagnose`.

    ``axes``: axis → {rms_baseline, rms_extended} (held-out residual RMS, deg/s); ``findings`` in
    order of addition; ``skipped``: vocabulary terms whose columns (or metadata) are absent, with
    ``skipped_reasons``; ``not_excited``: terms whose columns exist but do not vary enough on an
    axis (``"name:axis" -> reason``); ``noise_floor``: per-axis white-noise RMS estimated from
    successive differences of the extended model's residual (deg/s)."""

    source: str
    axes: dict[str, dict[str, float]]
    findings: list[Finding]
    skipped: list[str]
    skipped_reasons: dict[str, list[str]] = field(default_factory=dict)
    not_excited: dict[str, str] = field(default_factory=dict)
    noise_floor: dict[str, float] = field(default_factory=dict)
    rows: int = 0
    sample_rate_hz: float = float("nan")
    model_path: str | None = None
    base_model: dict[str, Any] | None = None
    fitted_baseline: dict[str, Any] = field(default_factory=dict)
    temperature_in_time: list[dict[str, Any]] = field(default_factory=list)
    """Axes whose fitted temperature cubic is material but the temperature moved only with time, so
    one run cannot tell it from a drift in time (``confounded.py``; deg/s, °C)."""
    rounds: list[list[dict[str, Any]]] = field(default_factory=list)
    dropped: list[dict[str, Any]] = field(default_factory=list)
    fixed_terms: list[str] = field(default_factory=list)
    unexplained: list[dict[str, Any]] = field(default_factory=list)
    """Structure left after selection that no vocabulary term names: per axis, its size (deg/s, per
    sample and on the block-mean band) and where it lives (``openworld.py``)."""
    band_s: float = float("nan")
    """Length of the blocks whose means form the slow band (s)."""
    noise: dict[str, dict[str, Any]] = field(default_factory=dict)
    """Per axis: the fitted noise model in IEEE 952 units, whether the fits were prewhitened by it,
    and the Allan read-outs of the residual (``noise.py``)."""
    structure: dict[str, dict[str, dict[str, Any]]] = field(default_factory=dict, repr=False)
    """``structure[stage][axis]`` for stage baseline/extended: the held-out residual's covariate
    correlations, Allan deviation vs white noise, spectra (``structure.analyse``)."""
    _internal: Any = field(default=None, repr=False)

    @property
    def json(self) -> dict[str, Any]:
        """The ``--json`` document (exact shape of ``docs/diagnose.md``)."""
        return {
            "axes": {a: {"rms_baseline": v["rms_baseline"], "rms_extended": v["rms_extended"]} for a, v in self.axes.items()},
            "findings": [f.as_json() for f in self.findings],
            "unexplained": _plain(self.unexplained),
            "skipped": list(self.skipped),
            "band_s": _num(self.band_s),
            "noise": _plain(self.noise),
            "temperature_in_time": _plain(self.temperature_in_time),
        }

    def summary_lines(self) -> list[str]:
        """Human summary: one line per axis, one per all-axes finding, then skipped terms."""
        lines = []
        for a, v in self.axes.items():
            mine = [f for f in self.findings if f.axis == a and not CANDIDATES[f.effect].noise_term]
            shared = [f for f in self.findings if f.axis == "all"]
            head = f"{a}: baseline residual {v['rms_baseline']:.2g} deg/s"
            left = [u for u in self.unexplained if u["axis"] == a]
            if not mine and not shared:
                floor = self.noise_floor.get(a)
                fl = f", noise floor {floor:.2g} deg/s" if floor else ""
                lines.append(f"{head} held-out{fl}: " + ("no named effect" if left else "nothing missing"))
                lines += [self.unexplained_line(u) for u in left]
                continue
            parts = [head] + [f"missing effect {f.effect}: {f.describe()}" for f in mine]
            if shared:
                parts.append("with " + ", ".join(f.effect for f in shared) + " (all axes)")
            ratio = v["rms_baseline"] / v["rms_extended"] if v["rms_extended"] > 0 else float("inf")
            parts.append(f"extended model {v['rms_extended']:.2g} deg/s held-out ({ratio:.2f}x per sample"
                         + _band_text(mine) + ")")
            lines.append("; ".join(parts))
            lines += [self.unexplained_line(u) for u in left]
        lines += [f"{d['axis']}: a warm-up was found but is not named: {d['reason']}" for d in self.dropped
                  if d.get("effect") == "warmup_transient" and str(d.get("reason", "")).startswith(UNBOUNDED)]
        lines += [in_time_line(e) for e in self.temperature_in_time]
        for a in self.axes:
            line = self.noise_line(a)
            if line:
                lines.append(line)
        for a in self.axes:
            line = self.structure_line(a)
            if line:
                lines.append(line)
        for f in self.findings:
            if f.axis == "all":
                lines.append(f"all axes: missing effect {f.effect}: {f.describe()}; held-out RMS "
                             f"{f.rms_before:.2g} -> {f.rms_after:.2g} deg/s ({f.gain:.1f}x)")
        if not self.findings and not self.unexplained:
            lines.append("nothing missing: the baseline model explains the data down to the noise")
        if self.skipped:
            lines.append("skipped (columns absent): " + ", ".join(
                f"{s} ({', '.join(self.skipped_reasons.get(s, []))})" for s in self.skipped))
        return lines

    def noise_line(self, axis: str) -> str | None:
        """The axis' noise model and the IEEE 952 read-outs of its residual, e.g. "y noise: white
        0.015 deg/√h + flicker B 29.2 deg/h + Gauss-Markov 0.033 deg/s, τc 2.02 s (named:
        angle_random_walk, bias_instability, gauss_markov); Allan read-out: ARW 3.2 deg/√h (τ 6 s), B 34.6 deg/h (τ 362 s)"."""
        sec = self.noise.get(axis)
        if not sec:
            return None
        named = sec.get("named") or [f.effect for f in self.findings if f.axis == axis and CANDIDATES[f.effect].noise_term]
        text = f"{axis} noise: {sec['describe']}"
        if named:
            text += f" (named: {', '.join(named)})"
        ro = sec.get("ieee952") or {}
        parts = []
        for key, label, unit in (("arw_deg_per_sqrt_h", "ARW", "deg/√h"), ("bias_instability_deg_per_h", "B", "deg/h"),
                                 ("rrw_deg_per_h_per_sqrt_h", "K", "deg/h/√h")):
            v = ro.get(key)
            if v is not None:
                how = ro.get(key.rsplit("_deg", 1)[0] + "_read") or {}
                est = ", estimate only" if how.get("estimate_only") else ""
                parts.append(f"{label} {v:.3g} {unit} (τ {how.get('tau_s', float('nan')):.3g} s{est})")
        if parts:
            text += "; Allan read-out: " + ", ".join(parts)
        for f in self.findings:
            alt = f.evidence.get("alternative") if f.axis == axis else None
            if alt:
                text += "; " + alternative_text(f.effect, alt)
                break
        return text

    def unexplained_line(self, u: dict[str, Any]) -> str:
        """One line for an unexplained-structure entry."""
        where = "; ".join(
            f"{w['against']}"
            + (f" at {w['frequency_hz']:.4g} Hz" if "frequency_hz" in w else "")
            + f" ({w['rms_dps']:.2g} deg/s per sample, {w['band_rms_dps']:.2g} deg/s on {self.band_s:.0f}-s means)"
            for w in u["where"])
        return (f"{u['axis']}: UNEXPLAINED structure the vocabulary does not name: {u['rms_dps']:.2g} deg/s "
                f"of the {u['residual_rms_dps']:.2g} deg/s held-out residual; lives against {where}")

    def structure_line(self, axis: str, stage: str = "baseline") -> str | None:
        """What the residual of ``stage`` on ``axis`` correlates with, when it is not white noise:
        covariates with |r| ≥ 0.2, Allan deviation over the white-noise line at the longest τ,
        the table-angle harmonic with the largest amplitude."""
        st = self.structure.get(stage, {}).get(axis)
        if not st:
            return None
        corr = sorted(((k, v) for k, v in st["correlations"].items() if math.isfinite(v) and abs(v) >= 0.2),
                      key=lambda kv: -abs(kv[1]))[:3]
        ratio = st.get("allan_ratio_max", float("nan"))
        if not corr and not (math.isfinite(ratio) and ratio > 2.0):
            return None
        parts = []
        if corr:
            parts.append("correlates with " + ", ".join(f"{k} (r = {v:+.2f})" for k, v in corr))
        if math.isfinite(ratio):
            parts.append(f"Allan deviation {ratio:.1f}x white noise at {st['allan_tau_s'][-1]:.4g} s")
        if "angle_peak" in st:
            n, amp = st["angle_peak"]
            parts.append(f"table-angle spectrum peak N = {n} ({100 * amp:.2g} % of rate)")
        return f"{axis} {stage} residual structure: " + "; ".join(parts)

    def extended_model(self) -> dict[str, Any]:
        """A sensor-model document (``schema: bench-sensor-model/1``) with the findings appended to
        ``effects:``: the model file's keys when one was given, else an ``npsat1_gyro`` model of
        the fitted baseline (bias polynomial, misalignment, white noise as angle random walk)."""
        if self.base_model is not None:
            out = {k: v for k, v in self.base_model.items() if k != "effects"}
            effects = list(self.base_model.get("effects") or [])
        else:
            out = {"schema": SCHEMA, "model": "npsat1_gyro",
                   "description": f"fitted by bench diagnose from {self.source}",
                   "source": "bench diagnose baseline fit (docs/diagnose.md)", **self.fitted_baseline}
            effects = []
        out["schema"] = SCHEMA
        out["effects"] = effects + [f.as_effect() for f in self.findings]
        return _plain(out)


def alternative_text(effect: str, alt: dict[str, Any]) -> str:
    """The sentence for a slow noise finding's ``alternative`` (``noise.alternative_evidence``)."""
    return (f"one run cannot tell {effect} from {alt['effect']} ({alt['describe']}; ΔIC {alt['d_ic']:+.0f}): only "
            f"{alt['draws_as_large']} of {alt['draws']} realisations of the noise model make a named slow shape as "
            f"large; what separates them: {alt['separated_by']}")


def _band_text(findings: list[Finding]) -> str:
    bands = [f.gain_band for f in findings if math.isfinite(f.gain_band)]
    return f", {max(bands):.2f}x on block means" if bands else ""


def _num(v: float) -> float | None:
    return float(v) if v is not None and math.isfinite(v) else None


def _evidence(ev: dict[str, Any]) -> dict[str, Any]:
    keep = ("d_ic", "phi", "t", "d_ic_given_probe", "allan_excess_slope", "allan_tau_range_s", "increment_kurtosis",
            "fitted_scale", "gain_heldout", "fitted_on", "noise_model", "d_bic", "tau_s_interval", "alternative")
    return {k: ev[k] for k in keep if k in ev}


def _plain(v: Any) -> Any:
    if isinstance(v, dict):
        return {str(k): _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple, np.ndarray)):
        return [_plain(x) for x in v]
    if isinstance(v, (np.floating,)):
        return float(v)
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v

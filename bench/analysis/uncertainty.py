"""GUM uncertainty budgets (JCGM 100:2008, "GUM"), as the ESTCube-2 thesis builds them (sections
3.2.2, 4.4, 5.4, 6.4).

A budget is a list of :class:`Component` rows. Each row has an input quantity's ``value`` in its
own ``units`` (type A: a standard deviation already evaluated from repeated observations; type B:
the half-width ``a`` of a rectangular/triangular/U-shaped interval or the standard deviation of a
normal one), a ``divisor`` from its distribution giving the standard uncertainty
``u_i = value / divisor``, and a sensitivity coefficient ``c_i`` (output units per input unit) giving
the contribution ``|c_i|·u_i`` in the output's units. Then (uncorrelated inputs, GUM 5.1.2)

* combined standard uncertainty ``u_c = √(Σ (c_i·u_i)²)``;
* effective degrees of freedom (Welch-Satterthwaite, GUM G.4.1) ``ν_eff = u_c⁴ / Σ (c_i u_i)⁴/ν_i``;
* coverage factor ``k``: given (default 2, the "95.45 % confidence level" of ESTCube-2 Tables
  4.3-6.3), or from Student's t at a coverage probability with ``dof`` (or ν_eff) degrees of
  freedom (ESTCube-2 Eq. 3.6: 95.45 %, 4 degrees of freedom → k = 2.869);
* expanded uncertainty ``U = k·u_c``.

:func:`bench_speed_budgets` applies this to the stepper bench speed calibration (ESTCube-2 Eq.
3.2-3.9) from the existing fit (:mod:`bench.analysis.bench_speed_fit`): u_speed = 0.006 deg/s,
extended 0.017 deg/s, u_n = 0.48, extended 1.4 from Table 3.1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from bench.analysis.bench_speed_fit import COVERAGE, BenchSpeedFit, fit_timings_file
from bench.analysis.result import ResultTable

DIVISORS: dict[str, float] = {
    "normal": 1.0,  # the value is already a standard uncertainty (GUM 4.3.3 with k = 1)
    "rectangular": math.sqrt(3.0),  # GUM 4.3.7: u = a/√3 (ESTCube-2 Eq. 3.3: Δ/√3)
    "triangular": math.sqrt(6.0),  # GUM 4.3.9: u = a/√6
    "u-shaped": math.sqrt(2.0),  # arcsine distribution on [−a, a]: variance a²/2
}
"""Divisor turning a type-B ``value`` into a standard uncertainty, by distribution."""
DEFAULT_K = 2.0
"""ESTCube-2 Tables 4.3-6.3 state totals at the "95.45 % confidence level" with k = 2 (e.g. Table 4.4:
√(0.0023² + 0.01² + 0.015² + 0.017²)·2 = 0.05 deg/s)."""
STOPWATCH_RESOLUTION_S = 0.01
"""ESTCube-2 Sec. 3.2.2: "The stopwatch has resolution Δ = 0.01 s"."""


@dataclass
class Component:
    """One row of a budget: input quantity ``name``, evaluation ``type`` ('A' or 'B'), ``value`` in
    ``units`` (see module docstring), ``distribution`` and ``divisor``, sensitivity coefficient
    ``sensitivity`` (output units per ``units``), degrees of freedom ``dof`` (inf for type B)."""

    name: str
    type: str
    value: float
    units: str
    distribution: str = "normal"
    divisor: float = 1.0
    sensitivity: float = 1.0
    dof: float = math.inf
    note: str = ""

    @property
    def std_uncertainty(self) -> float:
        """u_i = value / divisor, in ``units``."""
        return self.value / self.divisor

    @property
    def contribution(self) -> float:
        """|c_i|·u_i, in the budget's output units."""
        return abs(self.sensitivity) * self.std_uncertainty


def type_a(name: str, samples: np.ndarray | list[float], units: str, sensitivity: float = 1.0, note: str = "") -> Component:
    """Type A from repeated observations: the experimental standard deviation of the mean
    s/√n (GUM 4.2.3), n − 1 degrees of freedom."""
    x = np.asarray(samples, dtype=float)
    if x.size < 2:
        raise ValueError("a type A evaluation needs two or more observations")
    s = float(np.std(x, ddof=1))
    return Component(name, "A", s / math.sqrt(x.size), units, "normal", 1.0, sensitivity, float(x.size - 1),
                     note or f"std of the mean of {x.size} observations")


def type_a_std(name: str, std: float, units: str, dof: float, sensitivity: float = 1.0, note: str = "") -> Component:
    """Type A already evaluated as a standard deviation ``std`` (e.g. ESTCube-2 Eq. 3.2, the mean of
    the per-level standard deviations) with ``dof`` degrees of freedom."""
    return Component(name, "A", float(std), units, "normal", 1.0, sensitivity, float(dof), note)


def type_b(name: str, value: float, units: str, distribution: str = "rectangular", sensitivity: float = 1.0,
           note: str = "") -> Component:
    """Type B: ``value`` is the half-width a of the interval (rectangular, triangular, U-shaped) or
    the standard uncertainty (normal); divisor from :data:`DIVISORS`; infinite degrees of freedom."""
    if distribution not in DIVISORS:
        raise ValueError(f"unknown distribution {distribution!r} (known: {', '.join(DIVISORS)})")
    return Component(name, "B", float(value), units, distribution, DIVISORS[distribution], sensitivity, math.inf, note)


def student_k(probability: float, dof: float) -> float:
    """Coverage factor for ``probability`` (e.g. 0.9545) with ``dof`` degrees of freedom (Student's t,
    GUM G.3.2); the normal quantile for infinite dof. ESTCube-2 Eq. 3.6: (0.9545, 4) → 2.869."""
    q = 0.5 + probability / 2
    return float(stats.norm.ppf(q)) if math.isinf(dof) else float(stats.t.ppf(q, dof))


@dataclass
class UncertaintyBudget:
    """Rows, output units and the coverage rule: ``coverage_factor`` k when given; otherwise k from
    Student's t at ``coverage_probability`` with ``dof`` (or the Welch-Satterthwaite ν_eff)."""

    title: str
    output_units: str
    components: list[Component] = field(default_factory=list)
    coverage_factor: float | None = DEFAULT_K
    coverage_probability: float | None = None
    dof: float | None = None

    @property
    def combined(self) -> float:
        """Combined standard uncertainty u_c (output units), uncorrelated inputs (GUM 5.1.2)."""
        return math.sqrt(sum(c.contribution**2 for c in self.components))

    @property
    def effective_dof(self) -> float:
        """Welch-Satterthwaite ν_eff (GUM G.4.1); inf when every component has infinite dof."""
        den = sum(c.contribution**4 / c.dof for c in self.components if not math.isinf(c.dof) and c.contribution > 0)
        return math.inf if den == 0 else self.combined**4 / den

    @property
    def k(self) -> float:
        """The coverage factor used for the expanded uncertainty."""
        if self.coverage_factor is not None:
            return float(self.coverage_factor)
        p = self.coverage_probability if self.coverage_probability is not None else COVERAGE
        return student_k(p, self.dof if self.dof is not None else self.effective_dof)

    def expanded(self, sig_digits: int | None = None) -> float:
        """U = k·u_c (output units). With ``sig_digits``, u_c is first rounded to that many significant
        digits, as a thesis does when it multiplies its printed u_c (ESTCube-2 Eq. 3.6: 2.869 × 0.006)."""
        u = self.combined
        if sig_digits is not None and u > 0:
            u = round(u, sig_digits - 1 - int(math.floor(math.log10(u))))
        return self.k * u

    def as_json(self) -> dict[str, Any]:
        """Plain dict for ``--json`` (inf dof as null)."""
        def f(x: float) -> float | None:
            return x if math.isfinite(x) else None

        return {
            "title": self.title, "output_units": self.output_units,
            "components": [{"name": c.name, "type": c.type, "value": c.value, "units": c.units, "distribution": c.distribution,
                            "divisor": c.divisor, "std_uncertainty": c.std_uncertainty, "sensitivity": c.sensitivity,
                            "contribution": c.contribution, "dof": f(c.dof), "note": c.note} for c in self.components],
            "combined": self.combined, "effective_dof": f(self.effective_dof), "coverage_factor": self.k,
            "coverage_probability": self.coverage_probability, "expanded": self.expanded(),
        }

    def table(self) -> ResultTable:
        """The budget as a :class:`ResultTable` (one row per component, then u_c, k and U)."""
        rows: list[list[Any]] = []
        for c in self.components:
            rows.append([c.name, c.type, f"{c.value:.4g} {c.units}", c.distribution, f"{c.divisor:.4g}",
                         f"{c.std_uncertainty:.4g} {c.units}", f"{c.sensitivity:.4g}",
                         f"{c.contribution:.4g} {self.output_units}".strip(), "∞" if math.isinf(c.dof) else f"{c.dof:g}"])
        nu = self.dof if self.dof is not None else self.effective_dof
        rows.append(["combined standard uncertainty u_c", "", "", "", "", "", "", f"{self.combined:.4g} {self.output_units}".strip(),
                     "∞" if math.isinf(nu) else f"{nu:.3g}"])
        how = "given" if self.coverage_factor is not None else f"t, p = {self.coverage_probability or COVERAGE:.2%}"
        rows.append([f"coverage factor k ({how})", "", "", "", "", "", "", f"{self.k:.4g}", ""])
        rows.append(["expanded uncertainty U = k·u_c", "", "", "", "", "", "", f"{self.expanded():.4g} {self.output_units}".strip(), ""])
        return ResultTable(self.title, ["quantity", "type", "value", "distribution", "divisor", "std uncertainty",
                                        "sensitivity", "contribution", "dof"], rows)


def bench_speed_budgets(fit: BenchSpeedFit, resolution_s: float = STOPWATCH_RESOLUTION_S,
                        coverage_probability: float = COVERAGE) -> dict[str, UncertaintyBudget]:
    """The stepper bench speed and speed-parameter budgets of ESTCube-2 Sec. 3.2.2 from a fit of the
    rotation timings (:func:`bench.analysis.bench_speed_fit.fit_bench_speed`).

    Inputs (in s): the timing repeatability u_A (type A, Eq. 3.2: the mean of the per-n standard
    deviations, dof = repeats − 1) and the stopwatch resolution Δ (type B rectangular, Δ/√3, Eq. 3.3).
    Outputs: ``speed`` (deg/s) with sensitivity |d(360°/t)/dt| = 360/t² at the shortest mean rotation
    time (the largest speed, Eq. 3.5), and ``n`` with sensitivity dn/dt = k/(2π) (Eq. 3.7/3.8). Both
    use Student's t at 95.45 % with repeats − 1 degrees of freedom (Eq. 3.6/3.9: 2.869 for 5 repeats).
    """
    repeats = min(int(lv["repeats"]) for lv in fit.levels)
    dof = float(repeats - 1) if repeats > 1 else math.inf
    t_min = min(float(lv["mean_time_s"]) for lv in fit.levels)
    out = {}
    for key, title, units, c in (
        ("speed", "Stepper bench speed uncertainty (ESTCube-2 Eq. 3.2-3.6)", "deg/s", 360.0 / t_min**2),
        ("n", "Stepper bench speed parameter n uncertainty (ESTCube-2 Eq. 3.7-3.9)", "", fit.k / (2 * math.pi)),
    ):
        comps = [
            type_a_std("rotation time repeatability u_A (Eq. 3.2)", fit.u_a_s, "s", dof, c,
                       "mean of the per-n standard deviations of the timings"),
            type_b("stopwatch resolution Δ (Eq. 3.3)", resolution_s, "s", "rectangular", c,
                   "human reaction time taken as included in u_A (Sec. 3.2.2)"),
        ]
        out[key] = UncertaintyBudget(title, units, comps, coverage_factor=None, coverage_probability=coverage_probability,
                                     dof=dof)
    return out


def bench_speed_budgets_file(path: str | Path, resolution_s: float = STOPWATCH_RESOLUTION_S) -> dict[str, UncertaintyBudget]:
    """:func:`bench_speed_budgets` of a timings CSV (columns ``n``, ``rotation_time_s``);
    :class:`~bench.errors.InputError` for a bad file."""
    return bench_speed_budgets(fit_timings_file(path, resolution_s), resolution_s)

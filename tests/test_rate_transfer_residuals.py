"""Rate-transfer residuals: each step against its axis' line, the off-the-line flag and the
common-mode rates (``bench.analysis.rate_transfer.axis_residuals`` / ``common_mode``), on synthetic
steps with known displacements and on NPSAT1 Tables 9-11 (thesis section IV.E), whose expected values
are computed here with ``np.polyfit``, independently of the module."""

from __future__ import annotations

import csv
import json
import math
import os
import re
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from bench.analysis import rate_transfer
from bench.analysis.rate_transfer import axis_residuals
from bench.report import run_report
from tests.conftest import ROOT
from tests.test_calibration_methods import B_TRUE, M_TRUE, _rate_table_dataset, _schedule

TABLES_9_11 = ROOT / "tests" / "data" / "npsat1_tables_9_11.csv"
SEEDS_DIRS = ([Path(os.environ["BENCH_SEEDS"])] if os.environ.get("BENCH_SEEDS") else []) + \
    [p / "shared" / "seeds" for p in ROOT.parents] + [Path("/work/shared/seeds")]
"""Where the project's source documents may be: $BENCH_SEEDS, shared/seeds beside the checkout or above
it (a worktree), the workplace's own copy (a clone elsewhere)."""
THESIS = next((found for d in SEEDS_DIRS if (found := sorted(d.glob("000_*.txt")))), [])

SIGMA = 0.002  # deg/s, scatter of a synthetic step mean about its line
RATES = [5, 4, 3, 2, 1.5, 1, 0.5, 0.4, 0.3, 0.2, 0.1, 0.09, 0.07, 0.05, 0.03, 0.02]
RATES = [r for a in RATES for r in (a, -a)]  # 32 rates, + and −, as NPSAT1 Tables 9-11
LINES = {"x": (7.18e-3, 1.00042), "y": (-8.12e-3, 0.996), "z": (7.0e-3, 1.00506)}  # bias deg/s, slope


def _synthetic(rng, displace=None, sets=2):
    """Summary rows (axis, rate, set, mean) for x, y, z; ``displace``: {(axis, rate, set): deg/s}."""
    rows = []
    for a, (bias, slope) in LINES.items():
        for r in RATES:
            for k in range(1, sets + 1):
                m = bias + slope * r + rng.normal(0, SIGMA) + (displace or {}).get((a, r, k), 0.0)
                rows.append((a, r, k, m))
    return rows


def _run(tmp_path, rows, name="steps.csv", **opts):
    f = tmp_path / name
    f.write_text("axis,rate_dps,sample_set,mean_output_dps\n" + "".join(f"{a},{r!r},{k},{m!r}\n" for a, r, k, m in rows))
    return json.loads(json.dumps(rate_transfer.calibrate_summary_csv(f, **opts).json, allow_nan=False))


def _flagged(js):
    return {(a, s["rate_dps"]) for a, r in js["axes"].items() for s in r["steps"] if s["off"]}


# ---- synthetic -------------------------------------------------------------------------------------
def test_one_step_displaced_5_sigma_is_the_only_one_flagged(tmp_path):
    rng = np.random.default_rng(2024)
    js = _run(tmp_path, _synthetic(rng, {("z", 1, 1): 5 * SIGMA}))
    assert _flagged(js) == {("z", 1)}
    (hit,) = [s for s in js["axes"]["z"]["steps"] if s["off"]]
    assert hit["line"] == 2 + 2 * len(RATES) * 2 + 2 * RATES.index(1)  # the displaced row (set 1), not its twin
    assert hit["deleted_residual_dps"] == pytest.approx(5 * SIGMA, abs=2.5 * SIGMA)
    assert hit["t"] == pytest.approx(hit["deleted_residual_dps"] / hit["sigma_dps"])
    assert hit["sigma_dps"] == pytest.approx(SIGMA, rel=0.35)
    assert abs(hit["t"]) > js["axes"]["z"]["residuals"]["t_threshold"]
    assert js["common_mode"] == [] and js["common_mode_test"]["n_rates"] == len(RATES)


def test_5_sigma_step_power_and_no_common_mode_over_seeds(tmp_path):
    """Over 30 seeds: the displaced step is found about 2 times in 3 (t ≈ 5 ± 1 against a Bonferroni
    threshold ≈ 4.3; 6σ: 9 in 10), the 191 clean steps almost never, never a common-mode rate."""
    found = others = 0
    for seed in range(30):
        js = _run(tmp_path, _synthetic(np.random.default_rng(seed), {("y", -0.2, 2): -5 * SIGMA}), f"s{seed}.csv")
        flags = _flagged(js)
        found += ("y", -0.2) in flags
        others += len(flags - {("y", -0.2)})
        assert js["common_mode"] == []
    assert found >= 13 and others <= 2


def test_one_rate_displaced_on_every_axis_is_common_mode(tmp_path):
    rng = np.random.default_rng(7)
    d = 6 * SIGMA
    js = _run(tmp_path, _synthetic(rng, {(a, 0.3, k): d for a in "xyz" for k in (1, 2)}))
    assert [c["rate_dps"] for c in js["common_mode"]] == [0.3]
    c = js["common_mode"][0]
    assert set(c["axes"]) == {"x", "y", "z"} and c["same_sign"]
    for a, v in c["axes"].items():
        assert v["off"] and v["n_steps"] == 2
        assert v["deleted_residual_dps"] == pytest.approx(d, abs=3 * v["sigma_dps"])
        assert v["z"] == pytest.approx(v["deleted_residual_dps"] / v["sigma_dps"])
    # every other rate is clean on every axis
    assert {r for _, r in _flagged(js)} <= {0.3}
    # opposite signs on one axis: still common mode (a reference shift need not act alike), same_sign False
    js = _run(tmp_path, _synthetic(np.random.default_rng(7), {(a, 0.3, k): (-d if a == "y" else d) for a in "xyz" for k in (1, 2)}),
              "mixed.csv")
    assert [c["rate_dps"] for c in js["common_mode"]] == [0.3] and not js["common_mode"][0]["same_sign"]


def test_rate_displaced_on_two_of_three_axes_is_not_common_mode(tmp_path):
    js = _run(tmp_path, _synthetic(np.random.default_rng(8), {(a, -3, k): 8 * SIGMA for a in "xz" for k in (1, 2)}))
    assert js["common_mode"] == []
    assert {("x", -3), ("z", -3)} <= _flagged(js)


def test_clean_steps_false_alarm_rate(tmp_path):
    """50 clean seeds, 3 axes each at 1 % family-wise: at most a few seeds with any flag."""
    any_flag = common = 0
    for seed in range(100, 150):
        js = _run(tmp_path, _synthetic(np.random.default_rng(seed)), f"c{seed}.csv")
        any_flag += bool(_flagged(js))
        common += bool(js["common_mode"])
    assert any_flag <= 3 and common == 0


@pytest.mark.parametrize("between, within, sets", [(0.0, SIGMA, 2), (0.005, 0.0012, 2), (0.0, SIGMA, 1)])
def test_axis_residuals_family_wise_rate(between, within, sets):
    """The Bonferroni 1 % per axis holds (to within sampling) for independent steps, for repeats
    that share a per-rate error (NPSAT1-like: 0.005 between rates, 0.0012 within) and for single steps."""
    rng = np.random.default_rng(99)
    x = np.repeat(np.array(RATES, dtype=float), sets)
    n_sim, hits = 200, 0
    for _ in range(n_sim):
        y = 0.007 + 0.995 * x + np.repeat(rng.normal(0, between, len(RATES)), sets) + rng.normal(0, within, x.size)
        steps, rates, _ = axis_residuals(x, y, rate_tol_dps=1e-9)
        hits += any(s["off"] for s in steps)
    assert hits / n_sim <= 0.03


def test_textbook_externally_studentised_residual():
    """One step per rate, no known noise: t is the classic leave-one-out statistic, checked with np.polyfit."""
    rng = np.random.default_rng(5)
    x = np.array(RATES, dtype=float)
    y = 0.01 + 1.002 * x + rng.normal(0, SIGMA, x.size)
    steps, rates, info = axis_residuals(x, y, rate_tol_dps=1e-9)
    full = np.polyval(np.polyfit(x, y, 1), x)
    for i in (0, 7, 20):
        keep = np.arange(x.size) != i
        p = np.polyfit(x[keep], y[keep], 1)
        e = y[keep] - np.polyval(p, x[keep])
        s2 = e @ e / (keep.sum() - 2)
        xm = x[keep].mean()
        var = s2 * (1 + 1 / keep.sum() + (x[i] - xm) ** 2 / np.sum((x[keep] - xm) ** 2))
        d = y[i] - np.polyval(p, x[i])
        assert steps[i]["deleted_residual_dps"] == pytest.approx(d, abs=1e-12)
        assert steps[i]["t"] == pytest.approx(d / math.sqrt(var), rel=1e-9)
        assert steps[i]["dof"] == pytest.approx(x.size - 3)
        assert steps[i]["residual_dps"] == pytest.approx(y[i] - full[i], abs=1e-12)
        assert rates[[r["rate_dps"] for r in rates].index(x[i])]["z"] == pytest.approx(steps[i]["t"], rel=1e-9)
    assert info["t_threshold"] == pytest.approx(stats.t.isf(0.01 / x.size / 2, x.size - 3))  # Bonferroni, two-sided


def test_summary_csv_scatter_and_rounding_columns(tmp_path):
    """std_output_dps with n gives each step its own σ (std/√n); u_mean_dps adds in quadrature."""
    f = tmp_path / "s.csv"
    rows = ["axis,rate_dps,mean_output_dps,std_output_dps,n,u_mean_dps"]
    rng = np.random.default_rng(3)
    for r in RATES:
        rows.append(f"z,{r},{r + rng.normal(0, 0.001)!r},{0.001 * math.sqrt(20)!r},20,")
    rows[5] = rows[5].rsplit(",", 1)[0] + ",0.002"
    f.write_text("\n".join(rows) + "\n")
    js = rate_transfer.calibrate_summary_csv(f).json
    steps = js["axes"]["z"]["steps"]
    assert steps[0]["sigma_known_dps"] == pytest.approx(0.001)
    assert steps[4]["sigma_known_dps"] == pytest.approx(math.sqrt(0.001 ** 2 + 0.002 ** 2))
    assert js["axes"]["z"]["residuals"]["known_dps"] is not None and not any(s["off"] for s in steps)
    bad = tmp_path / "bad.csv"
    bad.write_text("axis,rate_dps,mean_output_dps,std_output_dps,n\nz,1,1.0,0.004,1\n")
    with pytest.raises(rate_transfer.InputError) as info:
        rate_transfer.calibrate_summary_csv(bad)
    assert info.value.field == "n" and ":2" in str(info.value)
    bad.write_text("axis,rate_dps,mean_output_dps,u_mean_dps\nz,1,1.0,-1\n")
    with pytest.raises(rate_transfer.InputError) as info:
        rate_transfer.calibrate_summary_csv(bad)
    assert info.value.field == "u_mean_dps"


def test_alpha_option(tmp_path):
    rows = _synthetic(np.random.default_rng(2024), {("z", 1, 1): 5 * SIGMA})
    assert _run(tmp_path, rows, "a.csv", alpha="1e-9")["axes"]["z"]["residuals"]["n_off"] == 0
    with pytest.raises(rate_transfer.InputError) as info:
        _run(tmp_path, rows, "b.csv", alpha=2)
    assert info.value.field == "alpha"


# ---- dataset input: the step's own scatter ----------------------------------------------------------
def _displaced_dataset(shifts):
    """The NPSAT1-like rate-table dataset of test_calibration_methods; ``shifts``: {(axis, rate): deg/s}
    added to that axis' output during its step at that rate."""
    ds = _rate_table_dataset(M_TRUE, B_TRUE, _schedule(), np.random.default_rng(17))
    for (a, r), d in shifts.items():
        on = np.isclose(ds[f"ref_rate_{a}_dps"], r, atol=1e-9)
        ds.columns[f"gyro_{a}_dps"] = np.where(on, ds[f"gyro_{a}_dps"] + d, ds[f"gyro_{a}_dps"])
    return ds


def test_dataset_step_uses_its_own_scatter_and_is_flagged():
    clean = rate_transfer.calibrate(_displaced_dataset({})).json
    s = [st for st in clean["axes"]["x"]["steps"] if st["rate_dps"] == 2.0][0]
    u = s["std_output_dps"] / math.sqrt(s["n"])  # white noise: n_eff ≈ n
    assert s["sigma_known_dps"] == pytest.approx(u, rel=0.15)
    js = rate_transfer.calibrate(_displaced_dataset({("x", 2.0): 6 * u})).json
    assert _flagged(js) == {("x", 2.0)} and js["common_mode"] == []
    hit = [st for st in js["axes"]["x"]["steps"] if st["off"]][0]
    assert hit["deleted_residual_dps"] == pytest.approx(6 * u, abs=2 * hit["sigma_dps"])


def test_dataset_rate_off_on_every_axis_is_common_mode():
    clean = rate_transfer.calibrate(_displaced_dataset({})).json
    u = max(st["sigma_dps"] for a in "xyz" for st in clean["axes"][a]["steps"])
    js = rate_transfer.calibrate(_displaced_dataset({(a, -0.5): -12 * u for a in "xyz"})).json
    assert [c["rate_dps"] for c in js["common_mode"]] == [pytest.approx(-0.5)]
    assert js["common_mode"][0]["same_sign"] and set(js["common_mode"][0]["axes"]) == {"x", "y", "z"}
    notes = rate_transfer.calibrate(_displaced_dataset({(a, -0.5): -12 * u for a in "xyz"})).notes
    assert any(n.startswith("common mode (off on every axis measured at the rate): -0.5 deg/s") for n in notes)


# ---- NPSAT1 Tables 9-11 -------------------------------------------------------------------------------
def _table_rows():
    with open(TABLES_9_11) as fh:
        return [r for r in csv.DictReader(line for line in fh if not line.startswith("#"))]


def _npsat1(tmp_path, sign=-1.0, name="npsat1.csv"):
    """Tables 9-11 "no ref" as a summary CSV. sign −1: the thesis' reading, output = rate·(1 − err/100)
    (docs/calibration.md); the printed 0.1 % steps of err give each mean a rounding uncertainty
    |rate|·0.001/√12."""
    rows = [r for r in _table_rows() if r["err_no_ref_pct"]]
    f = tmp_path / name
    f.write_text("axis,rate_dps,sample_set,mean_output_dps,u_mean_dps\n" + "".join(
        f"{r['axis']},{r['rate_dps']},{r['sample_set']},{float(r['rate_dps']) * (1 + sign * float(r['err_no_ref_pct']) / 100)!r},"
        f"{abs(float(r['rate_dps'])) * 0.001 / math.sqrt(12)!r}\n" for r in rows))
    return rows, json.loads(json.dumps(rate_transfer.calibrate_summary_csv(f).json, allow_nan=False))


@pytest.mark.skipif(not THESIS, reason="NPSAT1 thesis text (shared/seeds/000_*.txt beside or above the checkout, or $BENCH_SEEDS) not present")
def test_tables_9_11_transcription_matches_the_thesis_text_cell_by_cell():
    """Every cell of tests/data/npsat1_tables_9_11.csv against Tables 9, 10, 11 of the thesis text
    (section IV.E.2): rate, '*' (started >= 300 s after power-on), and the six cells per rate."""
    text = THESIS[0].read_text(encoding="utf-8").splitlines()
    start = next(i for i, ln in enumerate(text) if ln.startswith("Table 9. Z Sensor Output Error"))
    axis, parsed = None, []
    for ln in text[start:start + 200]:
        m = re.match(r"Table (9|10|11)\. ", ln)
        if m:
            axis = {"9": "z", "10": "x", "11": "y"}[m.group(1)]
            continue
        cells = [c.strip() for c in ln.split("\t")]
        if axis and re.fullmatch(r"-?[0-9.]+\*?", cells[0]) and len(cells) == 7:
            for k in (0, 1):
                c = ["" if v == "--" else v for v in cells[1 + 3 * k: 4 + 3 * k]]
                parsed.append([axis, cells[0].rstrip("*"), str(k + 1), "1" if cells[0].endswith("*") else "0", *c])
        if ln.startswith("Figure 40."):
            break
    assert parsed == [list(r.values()) for r in _table_rows()]


def test_npsat1_tables_9_11_steps_off_the_line_and_common_mode(tmp_path):
    rows, js = _npsat1(tmp_path)
    got = sorted((a, s["rate_dps"]) for a, r in js["axes"].items() for s in r["steps"] if s["off"])
    assert got == sorted([("x", 5.0), ("x", 5.0), ("x", -5.0), ("x", -5.0), ("x", 2.0),
                          ("y", 5.0), ("y", 5.0), ("y", -5.0), ("y", -5.0),
                          ("z", 5.0), ("z", 5.0), ("z", -5.0), ("z", -5.0)])
    # the x +2 deg/s step is sample set 2 (Table 10: 3.0 % error, STDV 0.348 deg/s against ~0.004)
    (x2,) = [s for s in js["axes"]["x"]["steps"] if s["off"] and s["rate_dps"] == 2.0]
    assert x2["mean_output_dps"] == pytest.approx(2 * (1 - 0.03))
    # independently: the line through the other steps (np.polyfit), per axis
    for a in "xyz":
        pts = [r for r in rows if r["axis"] == a]
        x = np.array([float(r["rate_dps"]) for r in pts])
        y = x * (1 - np.array([float(r["err_no_ref_pct"]) for r in pts]) / 100)
        bad = np.abs(x) == 5
        if a == "x":
            bad |= (x == 2) & (np.array([r["sample_set"] for r in pts]) == "2")
        p = np.polyfit(x[~bad], y[~bad], 1)
        e = y[~bad] - np.polyval(p, x[~bad])
        s = math.sqrt(e @ e / (e.size - 2))  # scatter of the clean steps about their line, deg/s
        assert 0.0012 < s < 0.0017
        want = (y - np.polyval(p, x))[bad]
        flagged = [st for st in js["axes"][a]["steps"] if st["off"]]
        assert [st["rate_dps"] for st in flagged] == x[bad].tolist()  # same steps, file order
        # y, z: the reference line is exactly that one; x also leaves out +2 set 1 and +4.5 (off as rates)
        assert [st["deleted_residual_dps"] for st in flagged] == pytest.approx(want.tolist(), abs=1e-9 if a != "x" else 1.5e-3), a
        assert np.all(np.abs(want) > 5.5 * s)  # every flagged step is > 5.5 clean σ off the clean line
        assert all(abs(st["t"]) > js["axes"][a]["residuals"]["t_threshold"] for st in flagged)
    # the figures quoted in docs/calibration.md
    z5 = sorted(st["deleted_residual_dps"] for st in js["axes"]["z"]["steps"] if st["rate_dps"] == 5)
    assert z5 == pytest.approx([-0.0440, -0.0390], abs=2e-4)
    # common mode: ±5 deg/s on all three axes; output magnitude below the line at both ends (same sign per rate)
    assert [c["rate_dps"] for c in js["common_mode"]] == [-5.0, 5.0]
    for c in js["common_mode"]:
        assert set(c["axes"]) == {"x", "y", "z"} and c["same_sign"]
        assert all(math.copysign(1, v["deleted_residual_dps"]) == -math.copysign(1, c["rate_dps"]) for v in c["axes"].values())
        assert all(abs(v["z"]) > 6 for v in c["axes"].values())
    assert js["common_mode_test"]["n_rates"] == 54  # rates of Tables 9 and 10 (Table 11 stops at ±0.06, inside them)


def test_npsat1_mirrored_reading_flags_the_same_steps(tmp_path):
    """The bench's own sign (output = rate·(1 + err/100)) mirrors each residual: same flags, signs flipped."""
    _, thesis = _npsat1(tmp_path)
    _, mirrored = _npsat1(tmp_path, +1.0, "mirrored.csv")
    assert _flagged(thesis) == _flagged(mirrored)
    for a in "xyz":
        for s, m in zip(thesis["axes"][a]["steps"], mirrored["axes"][a]["steps"]):
            assert m["residual_dps"] == pytest.approx(-s["residual_dps"], abs=1e-9)
            assert m["t"] == pytest.approx(-s["t"], rel=1e-6, abs=1e-9)


def test_npsat1_text_output_and_report_section(tmp_path):
    _, js = _npsat1(tmp_path)
    res = rate_transfer.calibrate_summary_csv(tmp_path / "npsat1.csv")
    titles = [t.title for t in res.tables]
    assert any(t.startswith("Residuals against the fit, axis z: off when p < 0.01/116") for t in titles)
    assert titles[-1].startswith("Common-mode rates")
    z = [t for t in res.tables if t.title.startswith("Residuals against the fit, axis z")][0]
    assert z.headers[-3:] == ["σ", "t", "off"] and sum(r[-1] == "OFF" for r in z.rows) == 4
    assert any(n.startswith("common mode (off on every axis measured at the rate): -5 deg/s") for n in res.notes)
    html = run_report.section_rate_transfer(js)
    assert "Steps off the line" in html and "Common-mode rates" in html

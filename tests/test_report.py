"""``bench report``: the self-contained HTML run report (bench/report/run_report.py, figures.py)."""

from __future__ import annotations

import base64
import json
import re
import shutil
import struct
import sys
import types
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

from bench.analysis.dataset import Dataset
from bench.analysis.result import CalibrationResult, ResultTable
from bench.errors import InputError
from bench.record.reader import EventRow, RunSummary, StepSummary, StreamSummary, read_run_summary
from bench.report import figures as F
from bench.report import run_report as R

SESSIONS = Path(__file__).resolve().parent / "sessions"
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
VOID = {"meta", "img", "br", "hr", "input", "link", "col", "area", "base", "source", "wbr"}


class _Page(HTMLParser):
    """Collects what the tests look at and checks that elements nest and close properly."""

    def __init__(self) -> None:
        super().__init__(convert_charrefs=True)
        self.stack: list[str] = []
        self.errors: list[str] = []
        self.imgs: list[str] = []
        self.urls: list[str] = []
        self.tags: list[str] = []
        self.classes: dict[str, list[str]] = {}
        self.step_rows = 0
        self.text: list[str] = []
        self._steps_depth: int | None = None
        self._in_tbody = False
        self._cls_stack: list[str] = []

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        self.tags.append(tag)
        for k in ("src", "href"):
            if a.get(k) is not None:
                self.urls.append(a[k])
        if tag == "img":
            self.imgs.append(a.get("src") or "")
        if tag in VOID:
            return
        self.stack.append(tag)
        self._cls_stack.append(a.get("class") or "")
        if tag == "div" and a.get("id") == "steps":
            self._steps_depth = len(self.stack)
        if self._steps_depth is not None and tag == "tbody":
            self._in_tbody = True
        if self._in_tbody and tag == "tr":
            self.step_rows += 1

    def handle_endtag(self, tag):
        if tag in VOID:
            return
        if not self.stack or self.stack[-1] != tag:
            self.errors.append(f"</{tag}> does not close <{self.stack[-1] if self.stack else 'nothing'}>")
            return
        if tag == "tbody":
            self._in_tbody = False
        if self._steps_depth is not None and len(self.stack) == self._steps_depth:
            self._steps_depth = None
        self.stack.pop()
        self._cls_stack.pop()

    def handle_data(self, data):
        self.text.append(data)
        cls = self._cls_stack[-1] if self._cls_stack else ""
        for c in cls.split():
            self.classes.setdefault(c, []).append(data)


def parse(html: str) -> _Page:
    p = _Page()
    p.feed(html)
    p.close()
    assert not p.errors, p.errors[:5]
    assert not p.stack, f"unclosed elements: {p.stack}"
    return p


def png_size(src: str) -> tuple[int, int]:
    """Width and height (px) of a data-URI PNG, checking the payload really is a PNG."""
    prefix = "data:image/png;base64,"
    assert src.startswith(prefix), src[:60]
    raw = base64.b64decode(src[len(prefix):], validate=True)
    assert raw[:8] == PNG_SIGNATURE
    return struct.unpack(">II", raw[16:24])


def check_images(p: _Page, at_least: int = 1) -> None:
    assert len(p.imgs) >= at_least
    for src in p.imgs:
        w, h = png_size(src)
        assert 200 <= w <= 1100 and h > 100


def check_self_contained(html: str, p: _Page) -> None:
    for url in p.urls:
        assert url.startswith("data:"), url[:80]
    assert "http://" not in html and "https://" not in html
    assert "script" not in p.tags and "link" not in p.tags


# ---- reports of recorded sessions -----------------------------------------------------------------
@pytest.mark.parametrize("name, status", [("rate_transfer_short", "COMPLETED"), ("chamber_short", "COMPLETED"),
                                          ("chamber_interlock_abort", "ABORTED")])
def test_report_of_session(name, status, tmp_path):
    run = SESSIONS / f"{name}.h5"
    summary = read_run_summary(run)
    out = R.write_report(run, tmp_path / "report.html")
    html = out.read_text(encoding="utf-8")
    assert html.startswith("<!DOCTYPE html>")
    p = parse(html)
    check_images(p)
    check_self_contained(html, p)
    assert p.step_rows == len(summary.steps) > 0
    text = " ".join(p.text)
    headings = re.findall(r"<h2>(\d+)\. ", html)
    assert headings == [str(n) for n in range(1, len(headings) + 1)] and len(headings) >= 4  # numbered in order
    assert status in " ".join(p.classes["pass" if status == "COMPLETED" else "fail"])
    assert summary.attrs["procedure_name"] in text
    if status == "ABORTED":
        assert summary.abort_reason and summary.abort_reason in " ".join(p.classes["fail"])
        assert "interlock" in summary.abort_reason


def test_rate_transfer_session_sections():
    html = R.build_report(SESSIONS / "rate_transfer_short.h5")
    p = parse(html)
    text = " ".join(p.text)
    assert len(p.imgs) >= 2  # environment (board temperatures) and rates
    assert "all 2 checks with limits passed" in text
    assert "sf_z" in text and "scale_factor_error" in text


def test_chamber_session_has_no_board_sections():
    p = parse(R.build_report(SESSIONS / "chamber_short.h5"))
    notes = " ".join(p.classes["note"])
    assert "no sensor data" in notes
    assert "Rates: not applicable: no gyro output" in notes
    assert len(p.imgs) == 1  # temperature and pressure only


def test_report_of_unreadable_files(tmp_path):
    good = (SESSIONS / "rate_transfer_short.h5").read_bytes()
    cases = {
        "truncated.h5": good[: len(good) // 2],
        "zeroed.h5": good[:8] + b"\0" * 4096 + good[4104:],
        "text.h5": b"not a run file\n",
        "empty.h5": b"",
    }
    for name, data in cases.items():
        path = tmp_path / name
        path.write_bytes(data)
        with pytest.raises(InputError, match="not a readable bench run file"):
            R.build_report(path)
    with pytest.raises(InputError):
        R.write_report(tmp_path / "missing.h5", tmp_path / "r.html")
    assert not (tmp_path / "r.html").exists()


def test_write_report_unwritable_destination(tmp_path):
    with pytest.raises(InputError, match="cannot write the report"):
        R.write_report(SESSIONS / "chamber_short.h5", tmp_path / "no" / "such" / "dir" / "r.html")


# ---- analysis guard ---------------------------------------------------------------------------------
def _fake_module(monkeypatch, name: str, calibrate) -> str:
    mod = types.ModuleType(name)
    mod.calibrate = calibrate
    monkeypatch.setitem(sys.modules, name, mod)
    return name


def test_run_analysis_guard(monkeypatch):
    ds = Dataset({"time_s": np.arange(3.0), "gyro_x_dps": np.zeros(3)}, source="synthetic")
    assert "not available" in R.run_analysis("bench.analysis.no_such_method_xyz", ds, "")
    assert R.run_analysis("x", None, "no board data").endswith("no board data")

    def not_applicable(d):
        raise InputError("needs a temperature column")

    assert "needs a temperature column" in R.run_analysis(_fake_module(monkeypatch, "fake_na", not_applicable), ds, "")

    def buggy(d):
        raise ZeroDivisionError("bug")

    with pytest.raises(ZeroDivisionError):
        R.run_analysis(_fake_module(monkeypatch, "fake_bug", buggy), ds, "")
    res = CalibrationResult("m", {"axes": {}})
    assert R.run_analysis(_fake_module(monkeypatch, "fake_ok", lambda d: res), ds, "") is res


def test_build_report_propagates_analysis_bugs(monkeypatch):
    def buggy(d):
        raise KeyError("bug in the analysis")

    monkeypatch.setitem(R.ANALYSES, "rate_transfer", (_fake_module(monkeypatch, "fake_rt_bug", buggy), "rate-transfer calibration"))
    with pytest.raises(KeyError):
        R.build_report(SESSIONS / "rate_transfer_short.h5")


def test_build_report_with_stubbed_analyses(monkeypatch):
    """Wiring of the analysis sections and the calibration tables: stub methods return synthetic JSON for
    the session's dataset (the thermal section made to apply: the session has no temperature sweep)."""
    monkeypatch.setattr(R, "why_no_sweep", lambda ds: "")
    thermal = CalibrationResult("thermal", _thermal_json(), [ResultTable("Thermal bias polynomial", ["axis", "c0"], [["z", 0.1]])],
                                notes=["synthetic"])
    monkeypatch.setitem(R.ANALYSES, "thermal", (_fake_module(monkeypatch, "fake_thermal", lambda d: thermal), "thermal calibration"))
    monkeypatch.setitem(R.ANALYSES, "rate_transfer",
                        (_fake_module(monkeypatch, "fake_rt", lambda d: CalibrationResult("rt", _rate_transfer_json())), "rate transfer"))
    monkeypatch.setitem(R.ANALYSES, "noise", (_fake_module(monkeypatch, "fake_noise", lambda d: CalibrationResult("noise", _allan_json())), "noise"))
    p = parse(R.build_report(SESSIONS / "rate_transfer_short.h5"))
    check_images(p, at_least=5)
    text = " ".join(p.text)
    assert "Thermal bias polynomial" in text and "synthetic" in text
    assert "ARW (deg/√h)" in text and "scale-factor error (%)" in text


# ---- section functions with synthetic JSON ------------------------------------------------------------
def _thermal_json() -> dict:
    return {"axes": {a: {"poly_degc": [0.1, -0.002, 1e-5, -1e-7], "poly_se": [1e-4, 1e-6, 1e-8, 1e-10], "residual_rms_dps": 0.01}
                     for a in "xyz"}}


def _rate_transfer_json() -> dict:
    steps = []
    for r in (5, -5, 0.5, -0.5, 0.05, -0.05, 0.0):
        m = 1.002 * r - 0.3
        steps.append({"rate_dps": r, "mean_output_dps": m, "percent_error": None if r == 0 else 100 * (m - r) / r,
                      "percent_error_ref": None if r == 0 else 100 * (m + 0.3 - r) / r})
    return {"axes": {"z": {"scale_factor_error": 0.002, "bias_dps": -0.3, "steps": steps}},
            "M": [[1.002, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]}


def _allan_json() -> dict:
    taus = np.geomspace(0.01, 1000, 20)
    adev = 0.02 * np.sqrt(0.01 / taus) + 1e-3 + 1e-6 * np.sqrt(taus)
    return {"axes": {a: {"arw_deg_per_sqrt_h": 0.12, "bias_instability_deg_per_h": 5.9 if a != "y" else None,
                         "rrw_deg_per_h_per_sqrt_h": None if a == "z" else 150.0,
                         "taus_s": taus.tolist(), "adev_dps": adev.tolist(),
                         "adev_lo_dps": (adev * 0.9).tolist(), "adev_hi_dps": (adev * 1.1).tolist()} for a in "xyz"}}


def _one_page(body: str) -> _Page:
    return parse(f"<div>{body}</div>")


def test_section_thermal_with_samples():
    n = 20000
    rng = np.random.default_rng(1)
    temp = np.linspace(-25, 65, n)
    c = _thermal_json()["axes"]["x"]["poly_degc"]
    cols = {"time_s": np.arange(n) * 0.01, "temp_c": temp, "ref_rate_z_dps": np.where(np.arange(n) % 4 == 0, 1.0, 0.0)}
    for a in "xyz":
        cols[f"gyro_{a}_dps"] = np.polynomial.polynomial.polyval(temp, c) + rng.normal(0, 0.01, n) + cols["ref_rate_z_dps"] * (a == "z")
    ds = Dataset(cols, source="synthetic")
    t, g, fitted = R.zero_rate_samples(ds)
    assert t.size == 3 * n // 4 and set(g) == {"x", "y", "z"} and fitted.all()
    ds.columns["power_on_s"] = ds["time_s"]
    t, g, fitted = R.zero_rate_samples(ds, 1e-4, 10.0)
    assert t.size == 3 * n // 4 and 0 < fitted.sum() < t.size
    p = _one_page(R.section_thermal(_thermal_json(), ds))
    check_images(p)
    assert "c3 = -1e-07" in " ".join(p.text)


def test_section_thermal_without_samples():
    p = _one_page(R.section_thermal(_thermal_json(), None))
    check_images(p)
    ds = Dataset({"time_s": np.arange(3.0), "temp_c": np.zeros(3), "gyro_x_dps": np.zeros(3), "ref_rate_x_dps": np.ones(3)})
    p = _one_page(R.section_thermal(_thermal_json(), ds))
    check_images(p)
    assert "No zero-rate samples" in " ".join(p.text)
    assert "no bias polynomial" in R.section_thermal({"axes": {}}, None)


def test_section_rate_transfer():
    p = _one_page(R.section_rate_transfer(_rate_transfer_json()))
    check_images(p)
    text = " ".join(p.text)
    assert "0.2" in text and "Scale-factor / misalignment matrix M" in text
    assert "no rate steps" in R.section_rate_transfer({"axes": {"x": {"steps": []}}})


def test_section_allan():
    p = _one_page(R.section_allan(_allan_json()))
    check_images(p)
    assert "0.12" in " ".join(p.text)
    assert "no Allan deviation" in R.section_allan({"axes": {}})


def _summary_with_checks() -> RunSummary:
    """A vibe_functional-like run: pre checks, a vibration step, post checks with references."""
    steps, events = [], []
    t = 0.0

    def add_step(name, typ, outcome, detail="", data=None):
        nonlocal t
        i = len(steps)
        steps.append(StepSummary(i, name, outcome, t, t + 10, typ, detail))
        if data is not None:
            events.append(EventRow(t + 10, 0.0, "check", name, i, f"{outcome}: ...", json.dumps(data).encode()))
        t += 10

    means = {}
    for stage, sf, bias in (("pre", 0.001, -0.30), ("post_z", 0.015, -0.33)):
        for r in (5, -5, 0.5, -0.5):
            w = f"{stage}_z_{r:+g}"
            add_step(f"record at {r:+g} deg/s", "record", "done", f"1000 rows in window '{w}'")
            means[w] = (1 + sf) * r + bias
        if stage == "post_z":
            add_step("random vibration z", "vibrate", "done")
        base = {"signal": "acs_board.gyro.z", "window": f"{stage}_z_*", "min": -0.05, "max": 0.05, "reference": None,
                "basis": "fit over 4 windows at 4 rates"}
        name_sf, name_b = ("pre_sf_z", "pre_bias_z") if stage == "pre" else ("post_z_sf_z_change", "post_z_bias_z_change")
        ref = stage != "pre"
        add_step(name_sf, "check", "failed" if ref else "passed", "...",
                 {**base, "name": name_sf, "statistic": "scale_factor_error", "value": sf, "outcome": "failed" if ref else "passed",
                  "reference": "pre_sf_z" if ref else None, **({"min": None, "max": None} if ref else {})})
        add_step(name_b, "check", "passed", "...",
                 {**base, "name": name_b, "statistic": "bias", "value": bias, "outcome": "passed",
                  "reference": "pre_bias_z" if ref else None, "min": None if ref else -0.4, "max": None if ref else 0.4})
    streams = [StreamSummary("acs_board", {"gyro": "deg/s", "temp": "degC"}, {"gyro": (3,), "temp": (3,)}, 100, 0.0, t, 100.0)]
    summary = RunSummary(Path("synthetic.h5"), {"procedure_name": "vibe_functional", "status": "completed"}, "completed", "", "",
                         {}, streams, steps, events, "")
    return summary, means


def test_check_results_and_units():
    summary, _ = _summary_with_checks()
    checks = R.check_results(summary)
    assert [c.name for c in checks] == ["pre_sf_z", "pre_bias_z", "post_z_sf_z_change", "post_z_bias_z_change"]
    assert R.display_value("scale_factor_error", 0.015, "deg/s") == (1.5, "%")
    assert R.display_value("slope", 2.0, "degC") == (2.0, "degC/s")
    assert R.signal_units(summary, "acs_board.gyro.z") == "deg/s"
    assert R.signal_units(summary, "tvac.air_temp") == ""
    assert [R._stage(c) for c in checks] == ["pre", "pre", "post_z", "post_z"]
    p = _one_page(R.section_verdict(summary, checks))
    assert "FAILED" in " ".join(p.classes["fail"])
    assert "1 of 4 checks failed: post_z_sf_z_change" in " ".join(p.text)


def test_section_pre_post():
    summary, means = _summary_with_checks()
    windows = R._windows(summary, np.zeros(0), None)
    assert [w.rate_dps for w in windows[:4]] == [5, -5, 0.5, -0.5]
    for w in windows:
        w.gyro_mean_dps = np.array([0.0, 0.0, means[w.name]])
    p = _one_page(R.section_pre_post(summary, R.RunData(windows=windows)))
    assert len(p.imgs) == 2  # values per stage, output error per window and stage
    check_images(p, at_least=2)
    text = " ".join(p.text)
    assert "1 vibration step(s)" in text
    assert "1.4" in text  # scale-factor error change: 1.5 % - 0.1 %
    assert "failed" in " ".join(p.classes["fail"])
    # without board data: the table and the per-stage values only
    assert len(_one_page(R.section_pre_post(summary, None)).imgs) == 1
    plain = RunSummary(Path("x.h5"), {}, "completed", "", "", {}, [], [], [], "")
    assert "No checks in this run compare" in R.section_pre_post(plain)


def test_section_tables():
    res = CalibrationResult("noise", {}, [ResultTable("Noise terms", ["axis", "ARW (deg/√h)"], [["x", "0.133"]])], notes=["short run"])
    p = _one_page(R.section_tables({"noise": res, "thermal": "No thermal calibration: why"}))
    text = " ".join(p.text)
    assert "Noise terms" in text and "0.133" in text and "short run" in text
    assert "No calibration ran" in R.section_tables({"thermal": "why"})


# ---- figures helpers ------------------------------------------------------------------------------------
def test_envelope_keeps_extremes_and_gaps():
    t = np.arange(200_000) * 0.01
    y = np.sin(t)
    y[12_345] = 50.0
    y[150_000] = -60.0
    tg, yg = F.break_gaps(np.delete(t, np.s_[100_000:110_000]), np.delete(y, np.s_[100_000:110_000]))
    assert np.isnan(yg).sum() == 1
    te, ye = F.envelope(tg, yg)
    assert te.size <= F.MAX_POINTS
    assert np.nanmax(ye) == 50.0 and np.nanmin(ye) == -60.0
    assert np.isnan(ye).sum() >= 1 and np.all(np.diff(te) >= 0)
    small_t, small_y = F.envelope(t[:100], y[:100])
    assert small_t.size == 100


def test_time_axis_units():
    assert F.time_axis(300) == (60.0, "run time (h:mm:ss)")
    assert F.time_axis(8 * 3600) == (3600.0, "run time (h:mm:ss)")
    assert R.hms(5.0) == "0:00:05" and R.hms(3725) == "1:02:05" and R.hms(None) == "-"


def test_html_cell_classes():
    from bench.report.html import Cell, table

    html = table(["a", "b"], [[Cell("failed", "fail"), 1.5], ["x", Cell(2.0, "pass")]])
    assert '<td class="l fail">failed</td>' in html and '<td class="pass">2</td>' in html
    assert table(["a"], [["x"]]) == table(["a"], [["x"]], left=1)  # plain tables unchanged


def test_copy_of_session_reports_its_own_path(tmp_path):
    run = tmp_path / "copy.h5"
    shutil.copy(SESSIONS / "chamber_short.h5", run)
    html = R.build_report(run)
    assert str(run.resolve()) in html

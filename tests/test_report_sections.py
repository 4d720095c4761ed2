"""``bench report``: which sections a run gets, noise only over static windows, the verdict and checks
first, one time unit (issue 17, part 3). Run files come from short dry-runs of the procedure library."""

from __future__ import annotations

import contextlib
import html as htmllib
import io
import json
import re
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from bench.record.reader import EventRow, RunSummary, StepSummary, StreamSummary
from bench.report import figures as F
from bench.report import run_report as R
from bench.report import static as S
from tests.conftest import ROOT, SIM_CONFIG, write_procedure
from tests.test_report import parse

SESSIONS = Path(__file__).resolve().parent / "sessions"
ANSWERS = ROOT / "procedures" / "answers" / "ci.yaml"
HMS = re.compile(r"^-?\d+:\d\d:\d\d$")


def dry_run(procedure: Path, runs: Path, *params: str) -> Path:
    """``bench run PROCEDURE --config configs/sim.yaml --sim`` in this process; the run file."""
    from bench.cli import main

    with contextlib.redirect_stdout(io.StringIO()) as out:
        code = main(["run", str(procedure), "--config", str(SIM_CONFIG), "--sim", "--runs-dir", str(runs),
                     "--answers", str(ANSWERS), *params])
    assert code == 0, out.getvalue()[-3000:]
    (path,) = runs.glob("*.h5")
    return path


@pytest.fixture(scope="module")
def thermal_ramp(tmp_path_factory) -> Path:
    """procedures/thermal_ramp_ambient.yaml, shortened: an 8 °C ramp recorded for 5 min from power-on
    (all of it warm-up for the thermal fit), then the wait until the mount is stable (recorded)."""
    return dry_run(ROOT / "procedures" / "thermal_ramp_ambient.yaml", tmp_path_factory.mktemp("ramp"),
                   "-p", "hot=30degC", "-p", "cold=22degC", "-p", "ramp=2degC/min", "-p", "ramp_record=300s",
                   "-p", "soak=1min", "-p", "hold=1min", "-p", "odr=10Hz")


@pytest.fixture(scope="module")
def thermal_sweep(tmp_path_factory) -> Path:
    """A 15-minute recording while the chamber heats at 3 °C/min: a sweep of about 6 °C after the
    warm-up, and no window at a stable temperature."""
    d = tmp_path_factory.mktemp("sweep")
    proc = write_procedure(d / "thermal_sweep.yaml", """\
  - power: {instrument: acs_board, on: true}
  - configure: {instrument: acs_board, odr: 10 Hz, moving_average: 1}
  - set_temperature: {instrument: tvac, set_point: 45 degC, ramp: 3 degC/min, name: ramp up}
  - record: {instrument: acs_board, duration: 900 s, window: ramp, name: record the ramp}
  - check: {name: die_rate, signal: acs_board.temp, statistic: slope, window: ramp}
  - check: {name: die_warmest, signal: acs_board.temp, statistic: max, window: ramp, max: 60 degC}
""", instruments="[acs_board, tvac]")
    return dry_run(proc, d / "runs")


@pytest.fixture(scope="module")
def allan_static(tmp_path_factory) -> Path:
    """procedures/allan_static.yaml, shortened: 5 min warm-up window, 10 min static window at 10 Hz."""
    return dry_run(ROOT / "procedures" / "allan_static.yaml", tmp_path_factory.mktemp("allan"),
                   "-p", "warmup=5min", "-p", "duration=10min", "-p", "odr=10Hz")


class Report:
    """A built report split into its sections: ``headings`` (h2 texts in order), ``body[heading]``
    (the section's HTML) and ``text[heading]`` (its text)."""

    def __init__(self, html: str) -> None:
        parse(html)  # well-formed
        self.html = html
        parts = re.split(r"<h2>(.*?)</h2>", html)
        self.headings = [htmllib.unescape(h) for h in parts[1::2]]
        self.body = dict(zip(self.headings, parts[2::2]))
        self.text = {h: htmllib.unescape(re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", b))).strip() for h, b in self.body.items()}

    def titles(self) -> list[str]:
        """Headings without their numbers."""
        return [re.sub(r"^\d+\. ", "", h) for h in self.headings]

    def section(self, title: str) -> str:
        """Text of the section titled ``title`` (without its number)."""
        for h, t in self.text.items():
            if re.sub(r"^\d+\. ", "", h) == title:
                return t
        raise KeyError(f"no section {title!r} in {self.headings}")

    def not_applicable(self) -> list[str]:
        """The items of the "Not applicable" list."""
        body = self.body.get("Not applicable to this run", "")
        return [htmllib.unescape(re.sub(r"<[^>]+>", "", li)) for li in re.findall(r"<li[^>]*>(.*?)</li>", body)]

    def tables(self, title: str) -> list[list[list[str]]]:
        """The tables of a section: rows of cell texts (header row first)."""
        h = next(h for h in self.headings if re.sub(r"^\d+\. ", "", h) == title)
        out = []
        for t in re.findall(r"<table>(.*?)</table>", self.body[h], re.S):
            rows = re.findall(r"<tr>(.*?)</tr>", t, re.S)
            out.append([[htmllib.unescape(re.sub(r"<[^>]+>", "", c)) for c in re.findall(r"<t[hd][^>]*>(.*?)</t[hd]>", r, re.S)]
                        for r in rows])
        return out


@pytest.fixture(scope="module")
def ramp_report(thermal_ramp) -> Report:
    return Report(R.build_report(thermal_ramp))


@pytest.fixture(scope="module")
def sweep_report(thermal_sweep) -> Report:
    return Report(R.build_report(thermal_sweep))


@pytest.fixture(scope="module")
def rate_report() -> Report:
    return Report(R.build_report(SESSIONS / "rate_transfer_short.h5"))


# ---- 1. sections only when they apply --------------------------------------------------------------
def test_thermal_ramp_report_has_no_rate_transfer_section(ramp_report):
    """A thermal ramp runs no rate steps: no rate-transfer section (it used to show the analysis'
    error), listed once at the end as not applicable, with the reason."""
    titles = ramp_report.titles()
    assert "Rate transfer" not in titles
    assert "rate-transfer" not in ramp_report.html.split("Not applicable to this run")[0]
    na = ramp_report.not_applicable()
    assert titles[-1] == "Not applicable to this run"
    assert sum(i.startswith("Rate transfer: not applicable: no rate steps were run") for i in na) == 1
    # 5 min of ramp from power-on is all warm-up for the thermal fit: no temperature sweep left
    (thermal,) = [i for i in na if i.startswith("Bias vs temperature: not applicable: ")]
    assert "no temperature sweep" in thermal and f"at least {R.TEMP_SWEEP_MIN_C:g} °C" in thermal
    assert len(na) == len(set(i.split(":")[0] for i in na))  # each section once


def test_thermal_sweep_report_has_bias_vs_temperature(sweep_report):
    titles = sweep_report.titles()
    assert "Bias vs temperature" in titles and "Rate transfer" not in titles
    assert "bias polynomial" in sweep_report.section("Bias vs temperature")
    assert any(i.startswith("Rate transfer: not applicable") for i in sweep_report.not_applicable())


def test_rate_transfer_session_sections(rate_report):
    titles = rate_report.titles()
    assert "Rate transfer" in titles and "Rates" in titles
    assert "Bias vs temperature" not in titles  # 30 s after power-on: all of it the warm-up the thermal fit leaves out
    assert "Bias vs temperature: not applicable: no zero-rate samples after the warm-up (the thermal fit's samples)." \
        in rate_report.not_applicable()


def test_chamber_session_without_board():
    rep = Report(R.build_report(SESSIONS / "chamber_short.h5"))
    na = rep.not_applicable()
    for title in ("Rates", "Bias vs temperature", "Rate transfer", "Noise (Allan deviation)", "Calibration tables"):
        assert title not in rep.titles()
        assert sum(i.startswith(f"{title}: not applicable: ") for i in na) == 1, (title, na)
    assert any("no ACS board data" in i for i in na)
    assert "Temperature and pressure" in rep.titles()


# ---- 2. noise only over static windows --------------------------------------------------------------
def test_noise_leaves_out_the_ramp(ramp_report):
    """The ramp window drifts by several °C: excluded, with the drift; the noise comes from the window
    at the cold end, where the mount was stable."""
    text = ramp_report.section("Noise (Allan deviation)")
    (windows,) = [t for t in ramp_report.tables("Noise (Allan deviation)") if t[0][0] == "window"]
    rows = {r[0]: r for r in windows[1:]}
    assert "sensor temperature drifts" in rows["ramp"][-1] and f"≤ {S.TEMP_DRIFT_MAX_C:g} °C" in rows["ramp"][-1]
    assert float(rows["ramp"][5]) > S.TEMP_DRIFT_MAX_C
    (used,) = [r for r in windows[1:] if r[-1] == "used"]
    assert used[0] == "step 9 (record until stable cold)"
    assert "Noise of the static window 'step 9 (record until stable cold)'" in text
    assert "ARW (deg/√h)" in text


def test_noise_without_static_window_says_why(sweep_report):
    text = sweep_report.section("Noise (Allan deviation)")
    assert "No noise analysis: no window is static: 1 window(s) with a temperature drift over 0.5 °C (ramp)" in text
    assert "ARW" not in text and "<img" not in sweep_report.body[next(h for h in sweep_report.headings if "Noise" in h)]
    assert not any(t[0][0] == "axis" for t in sweep_report.tables("Noise (Allan deviation)"))


def test_noise_of_allan_static_uses_static_not_warmup(allan_static):
    rep = Report(R.build_report(allan_static))
    (windows,) = [t for t in rep.tables("Noise (Allan deviation)") if t[0][0] == "window"]
    rows = {r[0]: r for r in windows[1:]}
    assert rows["static"][-1] == "used"
    assert "sensor temperature drifts" in rows["warmup"][-1]  # self-heating after power-on
    assert rows["static"][3] == str(6000)  # 10 min at 10 Hz, the sample closing the warm-up excluded


def test_noise_leaves_out_rate_steps(rate_report):
    (windows,) = [t for t in rate_report.tables("Noise (Allan deviation)") if t[0][0] == "window"]
    rows = {r[0]: r for r in windows[1:]}
    assert rows["z_set1_+1"][-1].startswith("rate step at +1 deg/s")
    assert "rate table moving at up to" in rows["z_set1_-0.5"][-1]
    used = [r[0] for r in windows[1:] if r[-1] == "used"]
    assert used and used[0].startswith("z_set1_zero_")


def _trace(label: str, t: np.ndarray, y: np.ndarray) -> S.Trace:
    return S.Trace(label, np.asarray(t, float), np.asarray(y, float))


def test_static_window_rules():
    t = np.arange(0.0, 100.0, 0.1)
    flat = _trace("sensor temperature", t, 25.0 + 0.01 * np.sin(t))
    assert S.check_window("a", 10.0, 90.0, 800, temperatures=[flat]).static
    # drift: 0.4 °C over the window is stable, 0.6 °C is not (the limit is 0.5 °C)
    for total, static in ((0.4, True), (0.6, False)):
        ramp = _trace("sensor temperature", t, 25.0 + total * t / 80.0)
        w = S.check_window("a", 10.0, 90.0, 800, temperatures=[ramp])
        assert w.static is static and w.temp_drift_c == pytest.approx(total, rel=1e-6)
    # the table turns although the window's name carries no rate; the monitor polls at 1 Hz
    tm = np.arange(0.0, 100.0, 1.0)
    table = _trace("rate table", tm, np.where((tm > 40) & (tm < 60), 0.01, 0.0))
    assert not S.check_window("b", 30.0, 70.0, 400, rates=[table]).static
    assert S.check_window("c", 70.0, 90.0, 200, rates=[table]).static
    # a window shorter than the poll interval takes the last reading before its end
    assert S.check_window("d", 50.2, 50.7, 5, rates=[table]).motion_dps == 0.01
    # a stepper bench turning 1 deg in 10 s, a tilt of the table, a shaker run
    bench = _trace("stepper bench", tm, np.where(tm > 20, np.minimum(tm - 20, 10) * 0.1, 0.0))
    assert "stepper bench moving" in S.check_window("e", 15.0, 35.0, 200, angles=[bench]).reasons[0]
    assert S.check_window("f", 40.0, 60.0, 200, angles=[bench]).static
    assert "vibrate" in S.check_window("g", 0.0, 10.0, 100, step_type="vibrate").reasons[0]
    assert S.check_window("h", 0.0, 10.0, 100, commanded_rate_dps=-0.5).reasons == ["rate step at -0.5 deg/s (window name)"]
    assert S.longest_static([S.check_window("x", 0, 1, 10), S.check_window("y", 0, 1, 20, commanded_rate_dps=1.0)]).name == "x"
    assert S.longest_static([S.check_window("y", 0, 1, 20, commanded_rate_dps=1.0)]) is None


# ---- 3. verdict and checks first, identity -------------------------------------------------------------
def test_report_opens_with_verdict_and_checks(rate_report):
    assert rate_report.headings[:4] == ["1. Verdict and checks", "2. Unit under test and run", "3. Steps",
                                        "4. Instruments and streams"]
    first = rate_report.body["1. Verdict and checks"]
    # a dry-run: its pass is never a plain green PASSED (issue 30), and it says why first
    assert first.lstrip().startswith('<p class="verdict warn" id="verdict">PASSED (DRY-RUN)</p>')
    assert "<li>DRY-RUN: simulated instruments, not acceptance evidence</li>" in first
    (checks,) = rate_report.tables("Verdict and checks")
    assert checks[0] == ["#", "check", "signal", "statistic", "window", "value", "limits", "outcome"]
    sf = next(r for r in checks if r[1] == "sf_z")
    assert sf[5].endswith(" %") and sf[6] == "-5 .. 5 %" and sf[7] == "passed (dry-run)"
    bias = next(r for r in checks if r[1] == "bias_z")
    assert bias[5].endswith(" deg/s") and bias[6] == "-0.4 .. 0.4 deg/s"


def test_identity_from_root_attributes(tmp_path, rate_report):
    unit = rate_report.tables("Unit under test and run")[0]
    assert unit[1:5] == [["unit serial", "not recorded"], ["unit part", "not recorded"], ["unit revision", "not recorded"],
                         ["station", "not recorded"]]  # a file from before these attributes
    run = tmp_path / "with_unit.h5"
    shutil.copy(SESSIONS / "rate_transfer_short.h5", run)
    with h5py.File(run, "r+") as f:
        f.attrs.update({"unit_serial": "SN-0042", "unit_part": "ACS-1", "unit_revision": "B", "station": "bench-2"})
    unit = Report(R.build_report(run)).tables("Unit under test and run")[0]
    assert unit[1:5] == [["unit serial", "SN-0042"], ["unit part", "ACS-1"], ["unit revision", "B"], ["station", "bench-2"]]


def test_thermal_ramp_checks_without_limits_give_no_verdict(ramp_report):
    first = ramp_report.section("Verdict and checks")
    assert first.startswith("NO VERDICT") and "no check in this run has limits" in first
    (checks,) = ramp_report.tables("Verdict and checks")
    assert {r[7] for r in checks[1:]} == {"recorded (no limits: no verdict)"}
    rate = next(r for r in checks if r[1] == "mount_rate")
    assert rate[5].endswith(" degC/s") and rate[6] == "none"


def _summary(checks: list[dict], status: str = "completed", planned: int | None = None) -> RunSummary:
    steps, events = [], []
    for i, d in enumerate(checks):
        steps.append(StepSummary(i, d["name"], d["outcome"], 10.0 * i, 10.0 * i, "check", "..."))
        events.append(EventRow(10.0 * i, 0.0, "check", d["name"], i, "", json.dumps(d).encode()))
    if planned is not None:
        events.append(EventRow(0.0, 0.0, "procedure", "", -1, "", json.dumps({"steps": planned}).encode()))
    streams = [StreamSummary("acs_board", {"gyro": "deg/s"}, {"gyro": (3,)}, 10, 0.0, 10.0, 1.0)]
    return RunSummary(Path("synthetic.h5"), {"mode": "hardware"}, status, "", "", {}, streams, steps, events,
                      "interlock tripped" if status == "aborted" else "")


def _check(name: str, outcome: str, lo: float | None = None, hi: float | None = None, value: float = 1.0) -> dict:
    return {"name": name, "signal": "acs_board.gyro.z", "statistic": "mean", "window": "w", "value": value, "min": lo,
            "max": hi, "reference": None, "outcome": outcome, "basis": ""}


def test_verdicts_and_recorded_checks():
    new = _check("mean z", "recorded")
    old = _check("mean y", "passed")  # a runner from before the recorded outcome wrote passed without limits
    limited = _check("bias z", "passed", -2.0, 2.0)
    cases = [
        (_summary([new, old]), "NO VERDICT"),
        (_summary([]), "NO VERDICT"),
        (_summary([new, limited]), "PASSED"),
        (_summary([limited, _check("sf z", "failed", None, 0.5)]), "FAILED"),
        (_summary([limited], status="aborted"), "INCOMPLETE"),
        (_summary([limited], planned=5), "INCOMPLETE"),
        (_summary([_check("sf z", "failed", None, 0.5)], status="aborted"), "FAILED"),
    ]
    for summary, word in cases:
        v = R.run_verdict(summary, R.check_results(summary))
        assert v.word == word, (word, v)
    summary = _summary([new, old, limited])
    assert [c.outcome for c in R.check_results(summary)] == ["recorded", "recorded", "passed"]
    v = R.run_verdict(summary, R.check_results(summary))
    assert v.reasons == ["the check with limits passed", "2 value(s) recorded without limits (no verdict)"]
    page = Report(f"<h2>1. Verdict and checks</h2>{R.section_verdict(summary, R.check_results(summary))}")
    (rows,) = page.tables("Verdict and checks")
    assert [r[5:] for r in rows[1:]] == [["1 deg/s", "none", "recorded (no limits: no verdict)"]] * 2 + [
        ["1 deg/s", "-2 .. 2 deg/s", "passed"]]
    assert R.limits_text(None, 5.0, "%") == "≤ 5 %" and R.limits_text(0.1, None, "") == "≥ 0.1"


def test_aborted_session_is_incomplete():
    rep = Report(R.build_report(SESSIONS / "chamber_interlock_abort.h5"))
    assert rep.section("Verdict and checks").startswith(
        "INCOMPLETE (DRY-RUN) DRY-RUN: simulated instruments, not acceptance evidence the run is aborted: ")


# ---- 4. one time unit ----------------------------------------------------------------------------------
def test_run_times_are_h_mm_ss(rate_report):
    (steps,) = rate_report.tables("Steps")
    assert steps[0][3:5] == ["start (h:mm:ss)", "duration (h:mm:ss)"]
    assert all(HMS.match(r[3]) and HMS.match(r[4]) for r in steps[1:])
    streams = rate_report.tables("Instruments and streams")[-1]
    assert streams[0][3] == "run time span (h:mm:ss)"
    assert all(all(HMS.match(x) for x in r[3].split(" – ")) for r in streams[1:])
    run = dict(rate_report.tables("Unit under test and run")[0][1:])
    assert re.match(r"^0:00:\d\d run time \(virtual clock\); 0:00:\d\d wall-clock$", run["duration (h:mm:ss)"])
    assert not re.search(r"\b\d+\.\d s\b", rate_report.text["3. Steps"] + rate_report.text["4. Instruments and streams"])
    assert R.hms(5.0) == "0:00:05" and R.hms(3725.4) == "1:02:05" and R.hms(-61) == "-0:01:01" and R.hms(None) == "-"


def test_figure_time_axes_are_h_mm_ss():
    assert {F.time_axis(span)[1] for span in (30, 300, 3600, 8 * 3600, 40 * 86400)} == {"run time (h:mm:ss)"}
    assert F.time_axis(30)[0] == 5 and F.time_axis(3600)[0] == 600 and F.time_axis(6.4 * 3600)[0] == 3600
    t = np.arange(0.0, 7200.0, 10.0)
    fig = F.fig_rates([F.Series("gyro x", t, np.sin(t))], [])
    fig.canvas.draw()
    ax = fig.axes[0]
    labels = [x.get_text() for x in ax.get_xticklabels() if x.get_text()]
    assert ax.get_xlabel() == "run time (h:mm:ss)" and "1:00:00" in labels and all(HMS.match(x) for x in labels)
    F.plt.close(fig)



# ---- 5. CLI tables at 80 columns ----------------------------------------------------------------------
def cli80(monkeypatch, capsys, *args: str) -> str:
    """``bench ARGS`` in this process with a rich console 80 columns wide (``COLUMNS=80``); stdout."""
    from bench.cli import main

    monkeypatch.setenv("COLUMNS", "80")
    capsys.readouterr()
    code = main(list(args))
    out = capsys.readouterr().out
    assert code in (0, 1), out[-2000:]
    return out


CUT = re.compile(r"…\s*[│┃]|…\s*$")
"""A cell rich cut short: its text ends in "…" (a "…" inside a value, as in "24.9 … 31.0", is content)."""


def assert_fits(out: str) -> None:
    """The output has tables, no table line is wider than 80 cells and no cell is cut to "…"."""
    from rich.cells import cell_len

    rows = [line for line in out.splitlines() if line[:1] in "┏┃┡│└"]
    assert rows, "no table in the output"
    assert not any(CUT.search(line) for line in rows), next(line for line in rows if CUT.search(line))
    assert max(cell_len(line) for line in rows) <= 80


@pytest.mark.parametrize("name, needles", [
    ("thermal_ramp_ambient.yaml", ["set_point 66 degC", "signal thermocouples.ch101", "timeout 43200 s", "ramp 0.47 degC/min",
                                   "duration 12166 s", "wait_until_stable (mount stable hot)", "3:22:46", "h:mm:ss"]),
    ("rate_transfer.yaml", ["table_rate (rate +5 deg/s)", "rate 5 deg/s", "angle -36.4 deg", "rate_table", "h:mm:ss"]),
])
def test_plan_table_at_80_columns(monkeypatch, capsys, name, needles):
    out = cli80(monkeypatch, capsys, "plan", str(ROOT / "procedures" / name), "--config", str(SIM_CONFIG))
    assert_fits(out)
    for needle in needles:
        assert needle in out, needle


def _calibration_cells(result) -> list[str]:
    return [f"{c:.6g}" if isinstance(c, float) else str(c) for t in result.tables for r in t.rows for c in r if c is not None]


@pytest.mark.parametrize("method, run", [("noise", "allan_static"), ("thermal", "thermal_sweep")])
def test_calibrate_tables_at_80_columns(monkeypatch, capsys, request, method, run):
    """Every value of every table in full, every header word (units included) present."""
    from bench.analysis.dataset import load_dataset
    from bench.cli_analysis import METHODS

    import importlib

    path = request.getfixturevalue(run)
    out = cli80(monkeypatch, capsys, "calibrate", method, str(path))
    assert_fits(out)
    module, func = METHODS[method]
    result = getattr(importlib.import_module(module), func)(load_dataset(path))
    lines = out.splitlines()
    for cell in _calibration_cells(result):
        assert any(cell in line for line in lines), cell
    for t in result.tables:
        for h in t.headers:
            for word in str(h).split():
                assert word in out, (h, word)


def test_run_summary_tables_at_80_columns(monkeypatch, capsys, tmp_path):
    out = cli80(monkeypatch, capsys, "run", str(ROOT / "procedures" / "allan_static.yaml"), "--config", str(SIM_CONFIG), "--sim",
                "--runs-dir", str(tmp_path), "-p", "warmup=1min", "-p", "duration=2min", "-p", "odr=10Hz")
    assert_fits(out)
    for needle in ("thermocouples.ch101", "acs_board.gyro.x", "'static'", "degC/s", "deg/s/s", "recorded", "warm-up transient"):
        assert needle in out, needle


def test_calibrate_bench_table_at_80_columns(monkeypatch, capsys):
    out = cli80(monkeypatch, capsys, "calibrate-bench", str(ROOT / "tests" / "data" / "estcube2_table_3_1.csv"))
    assert_fits(out)
    for needle in ("99.224", "3.6282", "deg/s", "rotation time"):
        assert needle in out, needle


def test_inspect_tables_at_80_columns(monkeypatch, capsys):
    out = cli80(monkeypatch, capsys, "inspect", str(SESSIONS / "rate_transfer_short.h5"), "--events", "12")
    assert_fits(out)
    for needle in ("'z_set1_zero_before'", "'z_set1_zero_after'", "scale_factor_error", "acs_board.gyro.z", "deg/s"):
        assert needle in out, needle

"""`bench diagnose` end to end on a run file recorded through the drivers, transports and recorder
(not the session generator), the binning of long data, and the progress lines of long analyses."""

from __future__ import annotations

import io
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import dry_run_file, run_cli

# A 25-minute chamber ramp with the board streaming at 100 Hz: 150,000 rows, more than
# BIN_MIN_ROWS, so diagnose analyses bin means. About 3 s of wall time in virtual time.
RAMP = """schema: bench-procedure/1
name: diagnose_ramp_short
title: Short chamber ramp recorded for bench diagnose (tests/test_diagnose_runfile.py)
instruments: [acs_board, tvac, thermocouples]
steps:
  - power: {instrument: acs_board, on: true, name: sensors on}
  - configure: {instrument: acs_board, odr: 100 Hz, moving_average: 1}
  - set_temperature: {instrument: tvac, set_point: 35 degC, ramp: 1 degC/min, name: ramp up}
  - record: {instrument: acs_board, duration: 25 min, window: ramp, name: record the ramp}
  - power: {instrument: acs_board, on: false, name: sensors off}
  - set_temperature: {instrument: tvac, set_point: 20 degC, name: back to ambient}
"""


def v_ok(v: dict) -> bool:
    return math.isfinite(v["rms_baseline"]) and 0 < v["rms_extended"] < v["rms_baseline"]


@pytest.fixture(scope="module")
def ramp_run(tmp_path_factory) -> Path:
    return dry_run_file(tmp_path_factory.mktemp("ramp"), "diagnose_ramp_short", RAMP)


def test_diagnose_recorded_run_json_report_and_model(ramp_run, tmp_path):
    from bench.record import read_run_summary

    report = tmp_path / "out.html"
    model = tmp_path / "extended.yaml"
    r = run_cli("diagnose", str(ramp_run), "--json", "--report", str(report), "-o", str(model), timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "Traceback" not in r.stderr
    doc = json.loads(r.stdout)  # stdout is only the JSON: every other line went to stderr
    assert set(doc["axes"]) == {"x", "y", "z"}
    # the simulated board's sensor (configs/sensors/acs_board_simple.yaml, NPSAT1 IV.A): a warm-up of
    # 0.024 / 0.017 / 0.019 deg/s settling in 720 / 510 / 300 s (τ = settling/3 = 240 / 170 / 100 s) on
    # every axis, white noise; nothing else is missing from the baseline (bias cubic in temperature)
    truth = {"x": (0.024, 240.0), "y": (0.017, 170.0), "z": (0.019, 100.0)}
    found = {f["axis"]: f for f in doc["findings"]}
    assert sorted((f["effect"], f["axis"]) for f in doc["findings"]) == [("warmup_transient", a) for a in "xyz"], doc
    assert doc["unexplained"] == []
    # the board's temperature only rises (20.1 -> 36.5 degC over the 25 min: its self-heating, then the
    # chamber's ramp): its cubic is a drift in time as much as a temperature coefficient, said on
    # every axis, nothing named for it (confounded.py; docs/diagnose.md, Output)
    said = {e["axis"]: e for e in doc["temperature_in_time"]}
    assert sorted(said) == ["x", "y", "z"] and all(e["monotone"] and e["temp_last_c"] > 35 for e in said.values()), said
    for a, (amp, tau) in truth.items():
        f = found[a]
        # within 30 %: the warm-up starts with the chamber ramp, so the fitted temperature cubic and the
        # transient share part of the first minutes (x and z come out 19-23 % high in amplitude)
        assert f["params"]["amplitude_dps"] == pytest.approx(amp, rel=0.3), (a, f)
        assert f["params"]["tau_s"] == pytest.approx(tau, rel=0.3), (a, f)
        lo, hi = f["evidence"]["tau_s_interval"]
        assert lo <= f["params"]["tau_s"] <= hi and hi < 3 * tau, (a, f["evidence"])
        assert f["gain"] > 1.05 and f["gain"] == pytest.approx(f["rms_before"] / f["rms_after"])
        assert v_ok(doc["axes"][a])
    # the board's white noise: the simulator draws σ = 0.005 deg/s/√Hz · √(π/2 · 12.5 Hz) = 0.0222 deg/s
    # per 100-Hz sample (MPU-6000, ESTCube-2 Tables 2.1 and 4.2), i.e. ARW = σ/√(100 Hz) = 0.133 deg/√h
    arw = 0.005 * math.sqrt(math.pi / 2 * 12.5) / math.sqrt(100.0) * 60.0
    for a, sec in doc["noise"].items():
        assert not sec["whitened"] and sec["model"]["arw_deg_per_sqrt_h"] == pytest.approx(arw, rel=0.15), (a, sec)
        assert sec["ieee952"]["arw_deg_per_sqrt_h"] == pytest.approx(arw, rel=0.15), (a, sec)

    # where the outputs went
    assert report.is_file() and report.read_text(encoding="utf-8").lstrip().lower().startswith("<!doctype html")
    assert f"report written to {report}" in r.stderr
    assert model.is_file() and "schema: bench-sensor-model/1" in model.read_text(encoding="utf-8")
    assert f"extended model written to {model}" in r.stderr

    # rows analysed: the board stream, as bin means of k rows
    (board,) = [s for s in read_run_summary(ramp_run).streams if s.key == "acs_board"]
    assert board.rows == 150_000
    m = re.search(r"analysed ([\d,]+) bin means of (\d+) rows \(([\d.]+) s\) from ([\d,]+) samples at ([\d.]+) Hz",
                  r.stderr)
    assert m, r.stderr
    bins, k, samples = int(m.group(1).replace(",", "")), int(m.group(2)), int(m.group(4).replace(",", ""))
    assert samples == board.rows
    assert k == 500 and float(m.group(3)) == pytest.approx(5.0)  # static data: 5-s means (BIN_MAX_STATIC_S)
    assert board.rows // k - 1 <= bins <= board.rows // k


def test_diagnose_recorded_run_human_output(ramp_run, tmp_path):
    report = tmp_path / "human.html"
    r = run_cli("diagnose", str(ramp_run), "--report", str(report), timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    out = r.stdout.splitlines()
    assert any(line.startswith("x: baseline residual") for line in out), r.stdout
    assert any(line.startswith("analysed 300 bin means of 500 rows") for line in out), r.stdout
    assert f"report written to {report}" in r.stdout
    assert report.is_file()


# ---- binning (bench/analysis/diagnose/data.py) ---------------------------------------------------
def _dataset(n: int, fs: float, **extra: np.ndarray):
    from bench.analysis.dataset import Dataset

    rng = np.random.default_rng(7)
    t = np.arange(n) / fs
    cols = {"time_s": t, "temp_c": 20.0 + 10.0 * t / t[-1], "power_on_s": t}
    for a in "xyz":
        cols[f"gyro_{a}_dps"] = 0.02 * rng.standard_normal(n)
    cols.update(extra)
    return Dataset(cols, {}, "synthetic")


def test_long_static_data_are_binned_to_five_second_means():
    from bench.analysis.diagnose.data import prepare

    ds = _dataset(150_000, 100.0)
    p = prepare(ds)
    assert p.bin_rows == 500 and p.raw_rows == 150_000 and p.raw_fs == pytest.approx(100.0)
    assert p.n == 300 and p.fs == pytest.approx(0.2)
    # bin means of every column, time the bin's mean time
    np.testing.assert_allclose(p.gyro["x"][:3], ds["gyro_x_dps"][:1500].reshape(3, 500).mean(axis=1))
    np.testing.assert_allclose(p.t[:2], [2.495, 7.495])
    # white noise of the means: variance / k
    assert np.std(p.gyro["y"]) == pytest.approx(0.02 / np.sqrt(500), rel=0.15)
    assert p.rows_line().startswith("analysed 300 bin means of 500 rows (5 s) from 150,000 samples at 100 Hz")


def test_static_data_leave_out_the_rows_where_the_unit_was_moved():
    """Handling between orientations (a few rows at hundreds of deg/s, as in the real CATS log) is left
    out of a static analysis, with a margin, and said; the rest is analysed as recorded."""
    from bench.analysis.diagnose.data import prepare

    ds = _dataset(20_000, 1.0)
    g = ds.columns["gyro_y_dps"]
    g[5000:5030] += 200.0  # 30 s of turning the unit by hand
    g[12000] -= 50.0
    p = prepare(ds)
    assert p.motion == (30 + 1 + 2 * 2 * 60, 2)
    assert p.n == 20_000 - p.motion[0]
    assert float(np.max(np.abs(p.gyro["y"]))) < 0.2
    assert "left out 271 rows in 2 stretch(es) where the unit was moved" in p.rows_line()
    quiet = prepare(_dataset(20_000, 1.0))
    assert quiet.motion == (0, 0) and quiet.n == 20_000


def test_short_data_are_not_binned():
    from bench.analysis.diagnose.data import prepare

    p = prepare(_dataset(72_000, 10.0))
    assert p.bin_rows == 1 and p.n == 72_000
    assert p.rows_line() == "analysed 72,000 rows at 10 Hz"


def test_rotating_table_keeps_the_angle_resolution():
    from bench.analysis.diagnose.data import prepare
    from bench.analysis.diagnose.terms import GearEccentricity

    n, fs, w = 150_000, 100.0, 1.0  # 1 deg/s: N = 360 has a 1-s period, 4 bins per period = 0.25 s
    t = np.arange(n) / fs
    ds = _dataset(n, fs, ref_rate_z_dps=np.full(n, w), ref_rate_x_dps=np.zeros(n), ref_rate_y_dps=np.zeros(n),
                  table_angle_deg=(w * t) % 360.0)
    p = prepare(ds)
    span = p.bin_rows / fs
    assert span <= 360.0 / (4 * GearEccentricity.N_MAX * w) + 1e-9
    assert p.bin_rows == 25
    # the angle is averaged unwrapped: no bin mean near 180 deg where the table crosses 360/0
    d = np.diff(np.unwrap(np.radians(p.angle)))
    np.testing.assert_allclose(np.degrees(d), w * span, rtol=1e-6)


def test_a_coherent_line_above_the_bins_is_fitted_on_the_raw_samples():
    """A 5-Hz line on 100-Hz static data no longer turns binning off (the 1e6-row case took 11.6 GB):
    it is fitted on the raw samples (frequency, amplitude, phase), removed before the 5-s bins, and
    reported as a periodic finding; narrow-band noise at the same frequency is not coherent and is
    left to the bins."""
    from bench.analysis.diagnose import diagnose
    from bench.analysis.diagnose.data import prepare

    n, fs = 150_000, 100.0
    ds = _dataset(n, fs)
    ds.columns["gyro_z_dps"] = ds["gyro_z_dps"] + 0.01 * np.sin(2 * np.pi * 5.0 * ds["time_s"] + 0.4)
    p = prepare(ds)
    assert p.bin_rows == 500
    (line,) = p.lines
    assert line.axis == "z" and line.frequency_hz == pytest.approx(5.0, abs=2e-4)
    assert line.amplitude_dps == pytest.approx(0.01, rel=0.05)
    assert "spectral line at 5 Hz on z" in p.rows_line() and "removed before binning" in p.rows_line()
    assert float(np.std(p.gyro["z"])) == pytest.approx(0.02 / np.sqrt(500), rel=0.2)  # nothing of it left
    (f,) = [f for f in diagnose(ds).findings if f.effect == "periodic"]
    assert f.axis == "z" and f.params["frequency_hz"] == pytest.approx(5.0, abs=2e-4)
    # the same power as narrow-band noise (a 5-Hz resonance driven by noise): not coherent, not fitted
    rng = np.random.default_rng(3)
    from scipy.signal import lfilter

    r = 0.995
    w0 = 2 * np.pi * 5.0 / fs
    ring = lfilter([1.0], [1.0, -2 * r * np.cos(w0), r * r], rng.standard_normal(n))
    ds2 = _dataset(n, fs)
    ds2.columns["gyro_z_dps"] = ds2["gyro_z_dps"] + 0.007 * ring / np.std(ring)
    assert prepare(ds2).lines == []


# ---- progress (bench/analysis/progress.py) ------------------------------------------------------
class _Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_progress_silent_at_first_then_throttled_lines():
    from bench.analysis.progress import Progress

    buf, clock = io.StringIO(), _Clock()
    with Progress("diagnose", buf, tty=False, heartbeat=False, clock=clock) as say:
        say("round 1")
        clock.t = 1.0
        say("round 2")
        assert buf.getvalue() == ""  # quick analyses print nothing
        clock.t = 2.5
        say("round 3")
        clock.t = 2.9
        say("round 4")  # within a second of the last line
        clock.t = 3.6
        say("round 5")
        clock.t = 5.0
        say("round 5")  # unchanged: repeated only every 10 s
    assert buf.getvalue().splitlines() == ["diagnose: round 3 (2 s)", "diagnose: round 5 (4 s)"]


def test_progress_on_a_terminal_rewrites_one_line_and_erases_it():
    from bench.analysis.progress import Progress

    buf, clock = io.StringIO(), _Clock()
    say = Progress("calibrate noise", buf, tty=True, heartbeat=False, clock=clock)
    clock.t = 3.0
    say("fitting")
    say.close()
    assert buf.getvalue() == "\rcalibrate noise: fitting (3 s)\x1b[K\r\x1b[K"


def test_nothing_is_written_once_closed_even_by_a_late_heartbeat():
    """A heartbeat thread that wakes after ``close`` (its join timed out on a loaded machine) must
    not print after the command's own last line."""
    from bench.analysis.progress import Progress

    buf, clock = io.StringIO(), _Clock()
    say = Progress("diagnose", buf, tty=False, heartbeat=False, clock=clock)
    clock.t = 2.5
    say("reading data.csv")
    say.close()
    clock.t = 20.0
    say._tick()  # what the heartbeat thread does when it wakes
    say("fitting")
    assert buf.getvalue() == "diagnose: reading data.csv (2 s)\n"


@pytest.mark.parametrize("label", ["diagnose", "report", "calibrate noise", "calibrate six-position", "calibrate rate-transfer"])
def test_the_tests_recognise_exactly_the_progress_lines_the_commands_write(label):
    """tests/cli_output.py drops progress lines before "one located error line": it must match
    every line Progress writes for the commands' labels, and no located message."""
    from bench.analysis.progress import Progress
    from tests.cli_output import is_progress

    buf, clock = io.StringIO(), _Clock()
    with Progress(label, buf, tty=False, heartbeat=False, clock=clock) as say:
        for t, message in enumerate(["reading /tmp/x y/data.csv", "round 1/6, candidates: 4/12 evaluated",
                                     "selecting again against the noise model (gyro_x_dps: white 1 (deg/s)^2)"]):
            clock.t = 2.0 + 2 * t
            say(message)
    lines = buf.getvalue().splitlines()
    assert len(lines) == 3 and all(is_progress(line) for line in lines), lines
    for located in ["/tmp/data.csv:2: sample_rate_hz: 0 Hz is outside the allowed range (0 s)",
                    "data.csv: gyro_x_dps: nothing to fit", "--report: FILE exists; choose another name or delete it",
                    "diagnose: reading data.csv (2 s) trailing", "note: 100 Hz (3 s)"]:
        assert not is_progress(located), located

"""Operator's station II (issue 30), the terminal side: what a technician met at 80x24 and each
fix's test. The web station's side is tests/test_web_station_ii.py.

1. a dry-run looked like a real run (run summary, inspect, report): banners and marked verdicts;
3. the person was not recorded: --operator, the lab's operators:, the origin;
4. units dropped between views: one formatter (check details, plan, live readings);
5. 80 columns: the progress line, watch at 80x24, inspect's checks and events;
7. errors: -p located at -p, an absent port said before anything is created;
8. help examples name files that exist, or say how to make them;
and `bench unit SERIAL` on a runs directory with several units and dry-runs mixed in.
"""

from __future__ import annotations

import json
import re
import threading
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
from rich.console import Console

from bench.cli import main
from tests.conftest import ROOT, SIM_CONFIG

ACCEPTANCE = ROOT / "tests" / "data" / "procedures" / "acceptance_short.yaml"
BANNER = "DRY-RUN: simulated instruments, not acceptance evidence"


def _cli(monkeypatch, capsys, *args: str) -> tuple[int, str, str]:
    monkeypatch.setenv("COLUMNS", "80")
    monkeypatch.setenv("LINES", "24")
    capsys.readouterr()
    code = main(list(args))
    out, err = capsys.readouterr()
    return code, out, err


def _cells(out: str) -> str:
    """The text of tables without their borders, white space collapsed."""
    return " ".join(re.sub(r"[│┃┏┓┗┛┡┩┢┪━─┳┻╇╈┼┬┴└┘┌┐]", " ", out).split())


def _table_lines(out: str) -> list[str]:
    return [line for line in out.splitlines() if not line.startswith("  bench ")]  # commands to copy stay whole


@pytest.fixture(scope="module")
def dry_run(tmp_path_factory) -> tuple[Path, str]:
    """A dry-run of the short acceptance test by `bench run` at 80 columns: (run file, its stdout)."""
    import contextlib
    import io
    import os

    d = tmp_path_factory.mktemp("dry")
    out = io.StringIO()
    env = {k: os.environ.get(k) for k in ("COLUMNS", "LINES")}
    os.environ.update(COLUMNS="80", LINES="24")
    try:
        with contextlib.redirect_stdout(out):
            code = main(["run", str(ACCEPTANCE), "--config", str(SIM_CONFIG), "--sim", "--runs-dir", str(d / "runs"), "--unit", "SN77",
                         "--operator", "ana"])
    finally:
        for k, v in env.items():
            os.environ.pop(k, None) if v is None else os.environ.__setitem__(k, v)
    assert code == 0, out.getvalue()
    (path,) = (d / "runs").glob("*.h5")
    return path, out.getvalue()


# ---- 1. a dry-run never passes for a real run -------------------------------------------------------
def test_the_run_summary_of_a_dry_run_says_so_and_keeps_units_at_80_columns(dry_run):
    _path, out = dry_run
    lines = _table_lines(out)
    assert max(len(line) for line in lines) <= 80, "\n".join(lines)
    assert "COMPLETED (DRY-RUN): all steps done; all 3 checks passed" in out
    assert lines[-1].strip() == BANNER or BANNER in out.split("COMPLETED (DRY-RUN)")[1]
    assert "(continued" not in out  # the checks in one table
    text = _cells(out)
    # the step detail and the checks table say the same, in the same units (a 5 % limit stays percent)
    from bench.record import read_run_summary

    detail = next(s.detail for s in read_run_summary(_path).steps if s.name == "sf_z")
    value = re.match(r"scale_factor_error acs_board\.gyro\.z = (-?\d[\d.]*) % \(limits -5 \.\. 5 %; fit over", detail)
    assert value, detail
    assert re.search(rf"sf_z {re.escape(value.group(1))} % -5 \.\. 5 % passed", text), text
    assert "-0.4 .. 0.4 deg/s" in text and "[-0.05, 0.05]" not in text


def test_inspect_of_a_dry_run_at_80_columns(dry_run, monkeypatch, capsys):
    path, _ = dry_run
    code, out, _ = _cli(monkeypatch, capsys, "inspect", str(path))
    assert code == 0
    assert out.splitlines()[0].strip() == BANNER
    assert max(len(line) for line in out.splitlines()) <= 80
    assert "(continued" not in out  # checks and events each one table, not two 40-row halves apart
    assert re.search(r"operator\s+ana \(cli \S+@", out)
    events = out[out.index("Events ("):]
    assert "{" not in events and '"answer"' not in events  # no raw JSON


def test_answers_and_controls_read_as_sentences():
    from bench.event_text import event_text

    answer = json.dumps({"id": "door", "text": "Close it", "answer": "yse", "source": "web 127.0.0.1", "operator": "ana",
                         "attempt": 1, "valid": False})
    assert event_text("operator", "prompt", answer) == "'yse' from ana (web 127.0.0.1) to door: not an accepted answer, asked again"
    stop = json.dumps({"action": "stop", "origin": "web 10.0.0.7", "operator": "bo", "message": "stop requested from the web station"})
    assert event_text("control", "web 10.0.0.7", stop) == "stop by bo (web 10.0.0.7)"
    assert event_text("note", "procedure", "{not json}") == "{not json}"


def test_the_report_of_a_dry_run_opens_with_its_banner(unit_runs, monkeypatch):
    """The page and its verdict (the analyses' sections are left out here: tests/test_report*.py)."""
    from bench.report.run_report import build_report

    real, dry = [], []
    for p in sorted(unit_runs.glob("*.h5")):
        (real if h5py.File(p, "r").attrs["mode"] == "hardware" else dry).append(p)
    from bench.report import run_report

    monkeypatch.setattr(run_report, "report_sections", lambda summary, data, ds, note: [
        run_report.Section("Verdict and checks", run_report.section_verdict(summary, run_report.check_results(summary)))])
    monkeypatch.setattr(run_report, "_load_dataset", lambda path, summary: (None, ""))
    html = build_report(dry[0])
    body = html[html.index("<body"):]
    assert body.index(BANNER) < body.index("<h1>") and 'data-mode="DRY-RUN"' in body
    assert '<p class="verdict warn" id="verdict">PASSED (DRY-RUN)</p>' in html
    html = build_report(real[0])  # a run on real instruments (the fixture's stand-in, see tests/unit_runs.py): no banner
    assert "mode-banner" not in html and '<p class="verdict pass" id="verdict">PASSED</p>' in html


# ---- 3. the person -----------------------------------------------------------------------------------
def test_the_operator_is_declared_and_recorded_with_its_origin(tmp_path, monkeypatch, capsys):
    config = tmp_path / "lab.yaml"
    text = SIM_CONFIG.read_text().replace("mode: sim ", "operators: [alice, Bob]\nmode: sim ", 1)
    config.write_text(text.replace("sensors/", str(ROOT / "configs" / "sensors") + "/"))
    proc = tmp_path / "w.yaml"
    proc.write_text("schema: bench-procedure/1\nname: w\ninstruments: [acs_board]\nsteps:\n  - wait: 1 s\n")
    runs = tmp_path / "runs"
    code, _, err = _cli(monkeypatch, capsys, "run", str(proc), "--config", str(config), "--runs-dir", str(runs), "--operator", "mallory")
    line = f"{config}:" if False else ""
    assert code == 2 and err.startswith("--operator: 'mallory' is not one of the lab's operators") and "alice, Bob" in err, err
    assert not runs.exists() or not list(runs.glob("*.h5"))
    code, _, err = _cli(monkeypatch, capsys, "run", str(proc), "--config", str(config), "--runs-dir", str(runs), "--operator", "bob")
    assert code == 0, err
    (path,) = runs.glob("*.h5")
    with h5py.File(path, "r") as f:
        assert f.attrs["operator"] == "Bob"  # the list's spelling
        assert re.fullmatch(r"cli \S+@\S+( tty)?", f.attrs["operator_origin"]), f.attrs["operator_origin"]
    del line


# ---- 4. units everywhere -------------------------------------------------------------------------------
def test_one_formatter():
    from bench.quantity_format import fmt_number, fmt_quantity, fmt_range, fmt_reading

    assert [fmt_number(v) for v in (760.0, 1.2e-5, 40.6912, -0.0012562, 0.0, 123456.0, 5.0, -0.00033287)] == \
        ["760", "1.2e-05", "40.69", "-0.001256", "0", "123456", "5", "-3.329e-04"]
    assert fmt_quantity(40.69, "degC") == "40.69 degC" and fmt_quantity(0.12562, "%") == "0.1256 %"
    assert fmt_quantity(0.5, "delta_degC") == "0.5 degC" and fmt_quantity(3, "1") == "3" and fmt_quantity(None, "deg") == "-"
    assert fmt_range(-33, 70, "degC") == "-33 .. 70 degC" and fmt_range(None, 2, "s") == "≤ 2 s" and fmt_range(None, None, "") == "none"
    assert fmt_reading(1591.0, "", "statusword") == "0x0637" and fmt_reading(3643.5, "", "statusword") == "3644"


def test_plan_shows_check_limits_in_their_units(monkeypatch, capsys):
    code, out, _ = _cli(monkeypatch, capsys, "plan", str(ROOT / "procedures" / "functional_test.yaml"))
    text = _cells(out)
    assert code == 0 and "limits -5 .. 5 %" in text and "limits -0.4 .. 0.4 deg/s" in text and "max 0.05" not in text
    code, out, _ = _cli(monkeypatch, capsys, "plan", str(ROOT / "procedures" / "thermal_ramp_ambient.yaml"))
    assert code == 0 and out.count("band 0.5 degC,") == 2 and "band 0.5," not in out  # the value with its unit, on one line


def test_live_readings_carry_units(tmp_path):
    """The progress line's readings (terminal and web): every polled value with its units."""
    from bench.config import load_config
    from bench.procedure import load_procedure
    from bench.runner.operator import Operator
    from bench.runner.session import start_run
    from tests.unit_runs import _Quiet

    proc = tmp_path / "p.yaml"
    proc.write_text("schema: bench-procedure/1\nname: p\ninstruments: [rate_table, tvac]\nsteps:\n"
                    "  - table_rate: {instrument: rate_table, rate: 5 deg/s}\n  - wait: 5 s\n")
    cfg = load_config(SIM_CONFIG)
    s = start_run(load_procedure(proc, kinds=cfg.kinds()), cfg, procedure_path=proc, config_path=SIM_CONFIG, runs_dir=tmp_path / "r",
                  sim=True, realtime=False, operator=Operator(None, None), progress=_Quiet())
    try:
        s.runner.run()
        readings = s.runner.monitor.readings()
    finally:
        s.lab.close()
    table = next(r for r in readings if r.startswith("rate_table "))
    assert re.fullmatch(r"rate_table angle \S+ deg, rate 5 deg/s, tilt \S+ deg", table), table
    chamber = next(r for r in readings if r.startswith("tvac "))
    assert re.fullmatch(r"tvac air_temp \S+ degC, mount_temp \S+ degC, pressure \S+ Torr", chamber), chamber


# ---- 5. 80 columns -------------------------------------------------------------------------------------
def test_the_progress_line_keeps_step_time_bar_and_units_at_80_columns():
    from types import SimpleNamespace

    from bench.runner.progress import RichProgress

    console = Console(record=True, width=80, force_terminal=False)
    p = RichProgress(console, dry_run=True)
    p._total = 1800.0
    p._started = time.monotonic() - 10.0
    p.step(8, 14, SimpleNamespace(name="record at +5 deg/s (zero-rate reference)"))
    p.advance(754.0, "gyro -1.148 +0.012 +5.001 deg/s, 24.0 degC; rate_table angle 41.86 deg, rate 5 deg/s, tilt -36.4 deg; "
                     "thermocouples ch101 20.17 degC, ch102 20.19 degC")
    console.print(p.view(80))
    lines = console.export_text().splitlines()
    assert all(len(line) <= 80 for line in lines), lines
    text = "\n".join(lines)
    assert "DRY-RUN  step 8/14 record at +5 deg/s (zero-rate reference)" in " ".join(text.split("\n")[:2])
    assert re.search(r"━+ 0:12:34 / 0:30:00 run time, \d:\d\d:\d\d left", lines[-2] if len(lines) > 2 else text), lines
    assert lines[-1].startswith("gyro -1.148 +0.012 +5.001 deg/s, 24.0 degC;") and lines[-1].endswith("…")
    p.paused = True
    console = Console(record=True, width=80)
    console.print(p.view(80))
    first = console.export_text().splitlines()[0]
    assert first.startswith(" PAUSED ") and "DRY-RUN" in first


def _monitor_file(tmp_path: Path) -> Path:
    """A run file written by the recorder: a board (gyro, status word) and three monitor streams."""
    from bench.record import Column, RunRecorder

    rec = RunRecorder.create(tmp_path, procedure_name="ramp", procedure_text="p", procedure_path="p.yaml", config_text="c",
                             config_path="c.yaml", mode="sim", software_version="test")
    board = rec.add_stream("acs_board", [Column("gyro", "deg/s", "f8", (3,)), Column("temp", "degC", "f8", (3,)),
                                         Column("status", "1", "u2")], rate_hz=100.0)
    tc = rec.add_stream("thermocouples", [Column(f"ch10{i}", "degC") for i in range(1, 5)], "monitor", rate_hz=1.0)
    ch = rec.add_stream("tvac", [Column("air_temp", "degC"), Column("mount_temp", "degC"), Column("pressure", "Torr")], "monitor", rate_hz=1.0)
    rt = rec.add_stream("rate_table", [Column("angle", "deg"), Column("rate", "deg/s"), Column("tilt", "deg"), Column("statusword", "1"),
                                       Column("tilt_statusword", "1")], "monitor", rate_hz=1.0)  # the columns of the real one
    rec.start()
    t = np.arange(0, 700.0, 0.01)
    spike = np.where(np.isclose(t, 699.99), 9.0, 0.1 * np.sin(t))  # the last value lies beyond every bin mean
    rec.append(board, t, gyro=np.stack([spike, spike, spike], axis=1), temp=np.full((len(t), 3), 24.0),
               status=np.where(t < 350, 0x0003, 0x0637).astype("u2"))
    ts = np.arange(0, 700.0, 1.0)
    rec.append(tc, ts, **{f"ch10{i}": 20.0 + ts / 100 for i in range(1, 5)})
    rec.append(ch, ts, air_temp=20 - ts / 50, mount_temp=20 - ts / 60, pressure=np.full(len(ts), 760.0))
    rec.append(rt, ts, angle=ts * 5, rate=np.full(len(ts), 5.0), tilt=np.full(len(ts), -36.4),
               statusword=np.where(ts < 350, 0x0637, 0x0237).astype(float), tilt_statusword=np.full(len(ts), 0x1640, dtype=float))
    rec.flush()
    rec.tick(699.99)
    rec.close("completed")
    return rec.path


def test_watch_fits_80x24_with_every_stream_and_honest_extremes(tmp_path):
    from bench.watch import build, snapshot

    state = snapshot(_monitor_file(tmp_path))
    console = Console(record=True, width=80, height=24)
    console.print(build(state, 80, 24))
    text = console.export_text()
    lines = text.splitlines()
    assert len(lines) <= 24 and max(len(line) for line in lines) <= 80, text
    for key in ("acs_board", "thermocouples/monitor", "tvac/monitor", "rate_table/monitor"):
        assert key in text, key
    assert re.search(r"pressure\s+760\s+Torr", text) and "7.6e+02" not in text and "ch101..ch104" in text
    assert BANNER in text
    assert "3643" not in text and "1319" not in text  # status words are never averaged
    assert re.search(r"statusword\s+0x0237\s.*seen: 0x0237, 0x0637", text), text
    for stream in state.streams:  # min and max are readings: the current value lies within them
        for sig in stream.signals:
            if sig.low == sig.low:
                assert sig.low <= sig.value <= sig.high, (stream.key, sig.label, sig.low, sig.value, sig.high)
    console = Console(record=True, width=80, height=22)  # tighter still: no table header, one line per status
    console.print(build(state, 80, 22))
    tight = console.export_text()
    assert len(tight.splitlines()) <= 22 and all(key in tight for key in ("acs_board", "rate_table/monitor", "tvac/monitor")), tight
    gyro = state.signal("acs_board", "gyro x")
    assert gyro.high == 9.0 and gyro.trend_max < 9.0  # a bin mean would have hidden it


# ---- the pause of a virtual-time run ------------------------------------------------------------------
def test_a_paused_dry_run_stands_still_in_virtual_time(tmp_path):
    """Issue 30 item 6: paused from the web, a virtual-time dry-run went from 0:25:00 to 2:16:50 in 3 s."""
    from bench.config import load_config
    from bench.procedure import load_procedure
    from bench.runner.operator import Operator
    from bench.runner.session import start_run
    from tests.unit_runs import _Quiet

    proc = tmp_path / "p.yaml"
    proc.write_text("schema: bench-procedure/1\nname: p\ninstruments: [acs_board, tvac]\nsteps:\n  - wait: 10 h\n")
    cfg = load_config(SIM_CONFIG)
    s = start_run(load_procedure(proc, kinds=cfg.kinds()), cfg, procedure_path=proc, config_path=SIM_CONFIG, runs_dir=tmp_path / "r",
                  sim=True, realtime=False, operator=Operator(None, None), progress=_Quiet())
    runner = s.runner
    thread = threading.Thread(target=runner.run)
    thread.start()
    try:
        deadline = time.monotonic() + 30
        while runner.clock.now() < 60 and time.monotonic() < deadline:
            time.sleep(0.01)
        runner.toggle_pause()
        time.sleep(0.3)
        t0 = runner.clock.now()
        time.sleep(1.0)
        held = runner.clock.now() - t0
        runner.toggle_pause()
        time.sleep(0.3)
        assert runner.clock.now() > t0  # resumed
    finally:
        runner.request_abort("test over")
        thread.join(60)
        s.lab.close()
    assert held == 0.0, f"virtual time went on {held:.0f} s while paused"


# ---- 7. errors -------------------------------------------------------------------------------------------
def test_a_parameter_error_is_located_at_the_option(monkeypatch, capsys):
    code, _, err = _cli(monkeypatch, capsys, "validate", str(ROOT / "procedures" / "thermal_ramp_ambient.yaml"), "-p", "cold=-29C")
    assert code == 2 and err.splitlines() == [
        "-p cold: '-29C' has units of [current] * [time], expected a quantity convertible to degC (the default is -29 degC; "
        "write the value with its units, e.g. -p cold=-29degC)"]


def test_an_absent_port_is_said_before_anything_is_created(tmp_path, monkeypatch, capsys):
    config = tmp_path / "lab.yaml"
    config.write_text("schema: bench-config/1\nname: bay\nmode: hardware\ninstruments:\n  acs_board:\n    driver: acs_board\n"
                      "    port: /dev/serial/by-id/usb-FTDI_absent-if00-port0\n    baudrate: 115200\n")
    proc = tmp_path / "r.yaml"
    proc.write_text("schema: bench-procedure/1\nname: r\ninstruments: [acs_board]\nsteps:\n  - record: {instrument: acs_board, duration: 5 s}\n")
    runs = tmp_path / "runs"
    code, out, err = _cli(monkeypatch, capsys, "run", str(proc), "--config", str(config), "--runs-dir", str(runs))
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1, err
    assert re.match(rf"{re.escape(str(config))}:\d+:\d+: acs_board: no such port /dev/serial/by-id/usb-FTDI_absent-if00-port0 → ",
                    lines[0]), lines[0]
    assert "'bench lab init' lists them" in lines[0] and lines[0].count("usb-FTDI_absent") == 1
    assert not runs.exists()  # no run file, no catalogue row: the run never started


# ---- 8. help ----------------------------------------------------------------------------------------------
def _helps() -> dict[str, str]:
    import argparse

    from bench.cli import build_parser

    out = {}

    def walk(p: argparse.ArgumentParser, name: str) -> None:
        out[name] = p.format_help()
        for a in p._actions:
            if isinstance(a, argparse._SubParsersAction):
                for sub, sp in a.choices.items():
                    walk(sp, f"{name} {sub}")

    walk(build_parser(), "bench")
    return out


def test_help_examples_use_files_that_exist_or_say_how_to_make_them():
    from bench.cli_common import LAB_CONFIG

    for name, text in _helps().items():
        examples = text[text.index("examples:"):] if "examples:" in text else ""
        for path in re.findall(r"(?<![\w/.-])((?:configs|procedures|tests)/[\w./-]+\.(?:yaml|csv|h5))", examples):
            if path == LAB_CONFIG:
                assert "bench lab init -o configs/lab.yaml" in " ".join(text.split()), name
            else:
                assert (ROOT / path).exists(), f"{name}: {path}"


def test_the_readme_opens_with_the_technicians_page_on_files_that_exist():
    readme = (ROOT / "README.md").read_text()
    first = readme[readme.index("## At the bench"):readme.index("## For developers")]
    assert readme.index("## At the bench") < min(readme.index(w) for w in ("SWMR", "Fletcher", "PDO"))
    for word in ("SWMR", "Fletcher", "PDO", "HDF5"):
        assert word not in first, word
    for verb in ("**Run**", "**Answer.**", "**Watch**", "**Pause or stop.**", "**Review**"):
        assert verb in first, verb
    commands = [line for block in re.findall(r"```sh\n(.*?)```", first, re.S) for line in block.splitlines()]
    assert commands and "bench lab init -o configs/lab.yaml" in first
    for line in commands:
        for path in re.findall(r"(?<![\w/.-])((?:configs|procedures)/[\w./-]+\.yaml)", line.split("#")[0]):
            assert path == "configs/lab.yaml" or (ROOT / path).exists(), line


# ---- bench unit -----------------------------------------------------------------------------------------
def test_bench_unit_history_at_80_columns(unit_runs, monkeypatch, capsys):
    code, out, _ = _cli(monkeypatch, capsys, "unit", "SN12", "--runs-dir", str(unit_runs))
    assert code == 0 and max(len(line) for line in out.splitlines()) <= 80, out
    assert "Unit SN12, part PN-100; its lot: 4 other unit(s) of PN-100" in out
    assert "1 of 3 run(s) are DRY-RUNs or replays" in out
    runs = [line for line in out.splitlines() if re.match(r"│ \d │ 2026-", line)]
    assert [("DRY-RUN" in r, "passed (dry-run)" in r) for r in runs] == [(True, True), (False, False), (False, False)]
    text = _cells(out)
    assert re.search(r"gyro z bias .*?OUTLIER of its lot", text) and "○●●" in text
    assert re.search(r"gyro z scale-factor .*?within its lot", text)
    code, out, _ = _cli(monkeypatch, capsys, "unit", "SN12", "--runs-dir", str(unit_runs), "--json")
    j = json.loads(out)
    bias = next(f for f in j["figures"] if f["name"] == "gyro z bias")
    assert bias["units"] == "deg/s" and bias["outlier"] and [p["evidence"] for p in bias["points"]] == [False, True, True]
    assert sorted(v["serial"] for v in bias["lot"]) == ["SN10", "SN11", "SN13", "SN14"] and all(v["evidence"] for v in bias["lot"])
    sf = next(f for f in j["figures"] if f["name"] == "gyro z scale-factor error")
    assert sf["units"] == "%" and not sf["outlier"]
    code, out, _ = _cli(monkeypatch, capsys, "unit", "SN13", "--runs-dir", str(unit_runs), "--json")
    assert not any(f["outlier"] for f in json.loads(out)["figures"])  # the lot's ordinary units are not flagged
    code, out, _ = _cli(monkeypatch, capsys, "unit", "SN20", "--runs-dir", str(unit_runs), "--json")
    assert all(f["verdict"].startswith("cannot tell: no other unit") for f in json.loads(out)["figures"])  # alone of its part
    code, _, err = _cli(monkeypatch, capsys, "unit", "SN99", "--runs-dir", str(unit_runs))
    assert code == 2 and err.startswith("SERIAL: no catalogued run of unit 'SN99'")


def test_bench_unit_acceptance_data_package(unit_runs, tmp_path, monkeypatch, capsys):
    out_file = tmp_path / "SN12.html"
    code, out, _ = _cli(monkeypatch, capsys, "unit", "SN12", "--runs-dir", str(unit_runs), "--html", "-o", str(out_file))
    assert code == 0 and " ".join(out.split()) == f"wrote {out_file}: 3 run(s) of SN12, 3 key figure(s)"
    html = out_file.read_text()
    assert "1 of 3 runs of SN12 are DRY-RUNs or replays" in html and html.count('src="data:image/png;base64,') == 3
    assert not re.search(r'(?:src|href)="(?!data:)', html)  # self-contained: nothing fetched
    assert "OUTLIER of its lot" in html
    code, _, err = _cli(monkeypatch, capsys, "unit", "SN12", "--runs-dir", str(unit_runs), "--html", "-o", str(out_file))
    assert code == 2 and "exists" in err

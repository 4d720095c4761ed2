"""The command line as an operator meets it (issue 17): help texts, ``--debug`` anywhere, outputs
never overwritten without ``--force``, quantities with units, the next commands after a run, a
light start, actionable ``instruments check`` hints and ``bench lab init``."""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import shutil
import socket
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from bench.errors import InputError
from tests.conftest import ROOT, SIM_CONFIG, run_cli

SESSION_RUN = ROOT / "tests" / "sessions" / "chamber_short.h5"
LAB_EXAMPLE = ROOT / "configs" / "lab.example.yaml"


# ---- help texts --------------------------------------------------------------------------------
def _commands(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()):
    """(command words, parser) for the top level and every subcommand, depth first."""
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _commands(sub, (*path, name))


def _all_commands():
    from bench.cli import build_parser

    return list(_commands(build_parser()))


@pytest.mark.parametrize("words,parser", _all_commands(), ids=lambda v: " ".join(v) if isinstance(v, tuple) else "")
def test_every_command_help_has_arguments_exit_codes_and_an_example(words, parser):
    text = parser.format_help()
    for action in parser._actions:
        if isinstance(action, (argparse._HelpAction, argparse._VersionAction, argparse._SubParsersAction)):
            continue
        name = action.dest if not action.option_strings else "/".join(action.option_strings)
        assert action.help and action.help is not argparse.SUPPRESS, f"bench {' '.join(words)}: {name} has no help"
        if action.option_strings and action.default not in (None, False, argparse.SUPPRESS, []):
            assert "default" in action.help, f"bench {' '.join(words)}: {name} does not say its default ({action.default!r})"
    assert "exit codes:" in text, f"bench {' '.join(words)}: no exit codes in --help"
    for code in ("0", "1", "2"):
        assert f"\n  {code}  " in text, f"bench {' '.join(words)}: exit code {code} not explained"
    assert "examples:\n  bench " in text, f"bench {' '.join(words)}: no example in --help"


def test_help_walk_sees_the_subcommands():
    words = {" ".join(w) for w, _ in _all_commands()}
    assert {"run", "validate", "inspect", "report", "soak", "instruments check", "lab init", "replay", "sim serve"} <= words


# ---- --debug anywhere --------------------------------------------------------------------------
@pytest.fixture
def bad_procedure(tmp_path: Path) -> Path:
    p = tmp_path / "bad.yaml"
    p.write_text("schema: bench-procedure/1\nname: bad\ninstruments: [acs_board]\nsteps:\n  - nonsense_step: {}\n")
    return p


@pytest.mark.parametrize("where", ["before", "after"])
def test_debug_is_accepted_before_and_after_the_command(bad_procedure, where):
    from bench.cli import main

    argv = ["--debug", "validate", str(bad_procedure)] if where == "before" else ["validate", str(bad_procedure), "--debug"]
    with pytest.raises(InputError):  # --debug: the error propagates (the traceback) instead of exit 2
        main(argv)


def test_without_debug_bad_input_is_one_line_exit_2(bad_procedure):
    r = run_cli("validate", str(bad_procedure))
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr and str(bad_procedure) in r.stderr


# ---- outputs are never overwritten without --force ---------------------------------------------
def _exists_message(option: str, path: Path) -> str:
    return f"{option}: {path} exists; choose another name or delete it"


@pytest.fixture
def csv_data(tmp_path: Path) -> Path:
    p = tmp_path / "data.csv"
    p.write_text("time_s,gyro_x_dps,gyro_y_dps,gyro_z_dps,temp_c\n" + "".join(f"{i},0.1,0.2,0.3,20\n" for i in range(50)))
    return p


@pytest.mark.parametrize("argv", [
    ("report", "{run}", "-o", "{out}"),
    ("diagnose", "{run}", "--report", "{out}"),
    ("diagnose", "{run}", "-o", "{out}"),
    ("calibrate", "noise", "{run}", "-o", "{out}"),
    ("import", "{csv}", "-o", "{out}"),
    ("lab", "init", "-o", "{out}"),
], ids=lambda a: " ".join(a[:2]) + " " + a[-2])
def test_existing_output_is_refused_with_exit_2(tmp_path, csv_data, argv):
    out = tmp_path / "existing.out"
    out.write_text("keep me\n")
    args = [a.format(run=SESSION_RUN, csv=csv_data, out=out) for a in argv]
    r = run_cli(*args)
    assert r.returncode == 2, r.stdout + r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(_exists_message(argv[-2], out)), r.stderr
    assert out.read_text() == "keep me\n"


def test_report_force_overwrites_and_never_its_input(tmp_path):
    run = tmp_path / "run.h5"
    shutil.copy(SESSION_RUN, run)
    out = tmp_path / "report.html"
    out.write_text("old\n")
    r = run_cli("report", str(run), "-o", str(out), "--force")
    assert r.returncode == 0, r.stderr
    assert out.read_text().startswith("<!DOCTYPE html>") or "<html" in out.read_text()
    assert not list(tmp_path.glob(".*partial*")), "a partial file was left behind"
    r = run_cli("report", str(run), "-o", str(run), "--force")
    assert r.returncode == 2 and "-o: " in r.stderr and "is also the input" in r.stderr, r.stderr
    assert run.read_bytes() == SESSION_RUN.read_bytes()


def test_output_file_keeps_the_old_file_when_the_writer_fails(tmp_path):
    from bench.outputs import output_file

    out = tmp_path / "x.txt"
    out.write_text("old")
    with pytest.raises(RuntimeError):
        with output_file(out, "-o", force=True) as tmp:
            tmp.write_text("half")
            raise RuntimeError("writer died")
    assert out.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["x.txt"]


# ---- quantities with units ---------------------------------------------------------------------
@pytest.fixture
def fake_soak(monkeypatch):
    seen: dict = {}

    def soak(config, hours, faults_per_hour, seed, runs_dir, **kw):
        seen.update(hours=hours, faults_per_hour=faults_per_hour)
        return SimpleNamespace(to_json=lambda: {}, crashes=0, unreadable_files=0, data_lost_rows=0, aborts=0, aborts_explained=0)

    monkeypatch.setattr("bench.soak.soak", soak)
    return seen


@pytest.mark.parametrize("options,hours,per_hour", [
    (["--hours", "2"], 2.0, 3.0),
    (["--hours", "2h"], 2.0, 3.0),
    (["--hours", "90min"], 1.5, 3.0),
    (["--duration", "2 h"], 2.0, 3.0),
    (["--duration", "30 min", "--faults-per-hour", "0.1/min"], 0.5, 6.0),
    (["--hours", "1", "--faults-per-hour", "4"], 1.0, 4.0),
])
def test_soak_takes_durations_and_rates_with_units(fake_soak, options, hours, per_hour):
    from bench.cli import main

    assert main(["soak", "--config", str(SIM_CONFIG), *options, "--json"]) == 0
    assert fake_soak["hours"] == pytest.approx(hours) and fake_soak["faults_per_hour"] == pytest.approx(per_hour)


@pytest.mark.parametrize("options,field", [
    (["--hours", "2 kg"], "--hours"),
    (["--duration", "soon"], "--duration"),
    (["--hours", "1", "--faults-per-hour", "3 m"], "--faults-per-hour"),
    (["--hours", "-1 h"], "--hours"),
])
def test_soak_bad_units_are_one_located_line(fake_soak, capsys, options, field):
    from bench.cli import main

    assert main(["soak", "--config", str(SIM_CONFIG), *options]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"{field}: "), err


def test_soak_needs_one_duration(fake_soak, capsys):
    from bench.cli import main

    with pytest.raises(SystemExit) as exc:
        main(["soak", "--config", str(SIM_CONFIG), "--hours", "1", "--duration", "1h"])
    assert exc.value.code == 2


# ---- after a run: the next commands ------------------------------------------------------------
def test_run_prints_the_next_commands_with_the_run_path(tmp_path):
    runs = tmp_path / "runs"
    r = run_cli("run", "procedures/functional_test.yaml", "--config", str(SIM_CONFIG), "--sim", "--runs-dir", str(runs),
                "--answers", "procedures/answers/ci.yaml")
    assert r.returncode == 0, r.stdout + r.stderr
    (path,) = sorted(runs.glob("*.h5"))
    out = " ".join(r.stdout.split())  # undo terminal wrapping
    for cmd in (f"bench inspect {path}", f"bench report {path} -o {path.with_suffix('.html')}", f"bench replay {path}",
                f"bench diagnose {path}"):
        assert cmd in out, cmd


# ---- a light start -----------------------------------------------------------------------------
HEAVY = ("numpy", "scipy", "h5py", "rich", "pint", "pymodbus", "canopen", "can", "serial", "matplotlib", "yaml")


def _modules_after(code: str) -> set[str]:
    out = subprocess.run([sys.executable, "-c", code + "\nimport sys; print(' '.join(sorted(sys.modules)))"],
                         cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    return set(out.stdout.split())


def test_parser_and_version_import_nothing_heavy():
    mods = _modules_after("import bench.cli\nbench.cli.build_parser()")
    assert not mods & set(HEAVY), sorted(mods & set(HEAVY))


def test_the_parser_of_one_command_is_that_command_of_the_whole_parser():
    """``bench CMD ...`` builds CMD's parser alone (bench.cli.parser_for): its help, its parsing and
    its errors are the whole parser's; no command, ``--help`` first or a misspelt command get the whole."""
    from bench.cli import build_parser, parser_for

    def sub_of(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
        (action,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        return dict(action.choices)

    whole = sub_of(build_parser())
    assert len(whole) >= 20
    for name, parser in whole.items():
        for argv in ([name], ["--debug", name, "--help"]):
            alone = sub_of(parser_for(argv))
            assert list(alone) == [name], argv
            assert alone[name].format_help() == parser.format_help(), argv
    for argv in ([], ["--help"], ["valdate", "x.yaml"], ["-h", "validate"], ["--debug", "--help"]):
        assert list(sub_of(parser_for(argv))) == list(whole), argv
    def exits(argv: list[str]) -> list[tuple[object, str, str]]:
        """Exit code, stdout and stderr of parsing ``argv`` that ends the program: one-command, whole."""
        said = []
        for parser in (parser_for(argv), build_parser()):
            out, err = io.StringIO(), io.StringIO()
            with pytest.raises(SystemExit) as stop, contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
                parser.parse_args(argv)
            said.append((stop.value.code, out.getvalue(), err.getvalue()))
        return said

    for argv in (["--version"], ["--debug", "--version", "validate"]):  # the version, before any command is looked at
        said = exits(argv)
        assert said[0] == said[1] and said[0][0] == 0 and said[0][1].startswith("bench "), (argv, said)
    args = ["validate", "procedures/startup_profile.yaml", "--config", "configs/sim.yaml", "-p", "cold=-20degC", "--debug"]
    assert vars(parser_for(args).parse_args(args)) == vars(build_parser().parse_args(args))
    for bad in (["validate", "--no-such-option", "x.yaml"], ["validate"], ["instruments", "bogus"], ["runs", "--since", "x", "-z"]):
        said = exits(bad)
        assert said[0] == said[1] and said[0][0] == 2 and "error:" in said[0][2], (bad, said)
    r = run_cli("sim")  # a command without its action: the whole usage, as before
    assert r.returncode == 2 and all(f" {c} " in r.stdout for c in ("validate", "replay", "sim", "fleet")), r.stdout


def test_validate_and_inspect_import_only_what_they_need():
    code = ("import contextlib, io\nfrom bench.cli import main\n"
            "with contextlib.redirect_stdout(io.StringIO()):\n"
            "    assert main(['validate', 'procedures/startup_profile.yaml']) == 0\n")
    mods = _modules_after(code)  # pint would import scipy (and dask, babel) only to know they are there: bench/units.py
    assert not mods & {"h5py", "pymodbus", "canopen", "can", "matplotlib", "scipy", "dask", "babel"}, sorted(mods & set(HEAVY))
    code = code.replace("'validate', 'procedures/startup_profile.yaml'", f"'inspect', {str(SESSION_RUN)!r}")
    mods = _modules_after(code)
    assert not mods & {"scipy", "pint", "pymodbus", "canopen", "can", "matplotlib"}, sorted(mods & set(HEAVY))


# ---- instruments check: one line per instrument, one hint per failure ----------------------------
def _config(tmp_path: Path, body: str):
    from bench.config import load_config

    p = tmp_path / "lab.yaml"
    p.write_text("schema: bench-config/1\nname: t\nmode: hardware\ninstruments:\n" + body)
    return load_config(p)


def _one_row(tmp_path, body, monkeypatch=None, ports=()):
    from bench import instruments_check

    if monkeypatch is not None:
        monkeypatch.setattr(instruments_check, "list_serial_ports", lambda: list(ports))
    (row,) = instruments_check.check_instruments(_config(tmp_path, body), sim=False)
    assert not row.ok
    return row


def test_missing_serial_port_lists_the_ports_seen_and_by_id(tmp_path, monkeypatch):
    from bench.instruments_check import SerialPort

    seen = SerialPort("/dev/ttyUSB7", "FT232R USB UART", 0x0403, 0x6001, "A10K1234",
                      "/dev/serial/by-id/usb-FTDI_FT232R_USB_UART_A10K1234-if00-port0")
    row = _one_row(tmp_path, "  acs_board: {driver: acs_board, port: /dev/ttyNOPE42}\n", monkeypatch, [seen])
    assert "no such port /dev/ttyNOPE42" in row.status
    assert "/dev/ttyUSB7" in row.hint and "0403:6001" in row.hint and seen.by_id in row.hint
    assert "/dev/serial/by-id/" in row.hint and "Errno" not in row.status + row.hint


def test_missing_serial_port_without_any_port_says_so(tmp_path, monkeypatch):
    row = _one_row(tmp_path, "  acs_board: {driver: acs_board, port: /dev/ttyNOPE42}\n", monkeypatch, [])
    assert "no serial ports" in row.hint and "docs/hardware.md" in row.hint


@pytest.fixture
def pty_path():
    master, slave = os.openpty()
    path = os.ttyname(slave)
    yield path
    os.close(slave)
    os.close(master)


def test_permission_denied_names_the_group_to_join(tmp_path, monkeypatch, pty_path):
    from bench import instruments_check

    os.chmod(pty_path, 0)  # enough for a normal user; root ignores it, so the check is also told
    real_access = os.access
    monkeypatch.setattr(instruments_check.os, "access", lambda p, m, **kw: False if str(p) == pty_path else real_access(p, m, **kw))
    monkeypatch.setattr(instruments_check, "serial_group", lambda path: "dialout")
    row = _one_row(tmp_path, f"  acs_board: {{driver: acs_board, port: {pty_path}}}\n")
    assert "permission denied" in row.status
    assert "sudo usermod -aG dialout $USER" in row.hint and "log in again" in row.hint


@pytest.mark.parametrize("os_release,group", [("ID=ubuntu\nID_LIKE=debian\n", "dialout"), ("ID=arch\n", "uucp"),
                                              ("ID=manjaro\nID_LIKE=arch\n", "uucp"), ("", "dialout")])
def test_serial_group_by_distribution(os_release, group):
    from bench.instruments_check import default_serial_group

    assert default_serial_group(os_release) == group


def test_missing_can_interface_says_how_to_bring_one_up(tmp_path):
    row = _one_row(tmp_path, "  rate_table: {driver: rate_table, port: 'can://socketcan/nocan7?node=1'}\n")
    assert "no CAN interface nocan7" in row.status
    assert "sudo ip link set nocan7 up type can bitrate 500000" in row.hint and "slcand" in row.hint


def test_modbus_tcp_refused_says_check_host_and_port(tmp_path):
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()  # nothing listens there now
    row = _one_row(tmp_path, f"  tvac: {{driver: tvac, port: 'modbus-tcp://127.0.0.1:{port}', gauge_port: 'loop://'}}\n")
    assert f"127.0.0.1:{port}" in row.status and "refused" in row.status
    assert "host" in row.hint and "port" in row.hint


def test_timeout_says_check_baud_rate_wiring_and_power(tmp_path, pty_path):
    row = _one_row(tmp_path, f"  stepper_bench: {{driver: stepper_bench, port: {pty_path}, timeout: 0.2 s}}\n")
    assert "no answer" in row.status
    assert "baud rate" in row.hint and "115200" in row.hint and "wiring" in row.hint and "power" in row.hint


def test_instruments_check_prints_one_line_per_instrument():
    r = run_cli("instruments", "check", "--config", str(LAB_EXAMPLE), timeout=180)
    assert r.returncode == 1, r.stdout + r.stderr
    lines = r.stdout.strip().splitlines()
    from bench.config import load_config

    names = tuple(load_config(LAB_EXAMPLE).instruments)  # the example lab's instruments, whatever they are
    assert names
    for name in names:
        mine = [ln for ln in lines if ln.split(":", 1)[0].strip() == name]
        assert len(mine) == 1, (name, lines)
        assert "→" in mine[0], mine[0]  # the hint
        assert mine[0].count("Errno") <= 1, mine[0]
    assert len(lines) == len(names) + 2, lines  # a heading, one line each, a summary


# ---- bench lab init ----------------------------------------------------------------------------
def test_lab_init_skeleton_loads_once_a_driver_is_chosen(tmp_path, monkeypatch, capsys):
    from bench import instruments_check
    from bench.cli import main
    from bench.config import load_config
    from bench.instruments_check import SerialPort

    port = SerialPort("/dev/ttyUSB0", "FT232R USB UART", 0x0403, 0x6001, "A10K1234",
                      "/dev/serial/by-id/usb-FTDI_FT232R_USB_UART_A10K1234-if00-port0")
    monkeypatch.setattr(instruments_check, "list_serial_ports", lambda: [port])
    monkeypatch.setattr("bench.lab_init.can_interfaces", lambda: [])
    out = tmp_path / "lab.yaml"
    assert main(["lab", "init", "-o", str(out), "--station", "gyro-lab-2"]) == 0
    text = out.read_text()
    assert port.by_id in text and "0403:6001" in text and "FT232R USB UART" in text
    from bench.kinds import registry

    for driver in registry.kinds():  # every installed kind is offered (a lab's own package's too)
        assert driver in text, driver
    assert "sim:" in text and "station: gyro-lab-2" in text
    with pytest.raises(InputError, match="driver"):
        load_config(out)  # the driver is still to be chosen: a located error says so
    chosen = out.with_name("chosen.yaml")
    chosen.write_text(text.replace("driver: CHOOSE", "driver: acs_board", 1).replace("  ttyUSB0:", "  acs_board:", 1))
    config = load_config(chosen)
    assert config.instruments["acs_board"].port == port.by_id and config.station == "gyro-lab-2"
    assert main(["validate", "procedures/startup_profile.yaml", "--config", str(chosen)]) == 0
    # the sim section, once uncommented, is accepted too
    simmed = chosen.with_name("simmed.yaml")
    simmed.write_text(chosen.read_text().replace("# sim: {backend: SAME_AS_DRIVER}", "sim: {backend: acs_board}", 1))
    assert load_config(simmed).instruments["acs_board"].sim is not None
    # an existing file is kept unless --force
    capsys.readouterr()
    assert main(["lab", "init", "-o", str(out)]) == 2
    assert _exists_message("-o", out) in capsys.readouterr().err
    assert main(["lab", "init", "-o", str(out), "--force", "--station", "other"]) == 0
    assert "station: other" in out.read_text()


def test_lab_init_without_ports_still_writes_a_skeleton(tmp_path, monkeypatch):
    from bench import instruments_check
    from bench.cli import main

    monkeypatch.setattr(instruments_check, "list_serial_ports", lambda: [])
    monkeypatch.setattr("bench.lab_init.can_interfaces", lambda: ["can0"])
    out = tmp_path / "lab.yaml"
    assert main(["lab", "init", "-o", str(out)]) == 0
    text = out.read_text()
    assert "no serial ports" in text and "can://socketcan/can0?node=1" in text

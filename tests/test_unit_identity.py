"""Unit under test, station and instrument calibration (issue 17, part 1): what `bench run` records
(`--unit/--part/--revision/--station`, the config's `station:`, `serial:`, `firmware:`,
`calibration_due:`), what it refuses (a procedure with `requires: {unit: true}` without `--unit`,
bad identity texts and dates, an overdue calibration nobody confirms) and what `bench inspect`
shows. Dry-runs of a 1-s procedure on configs/sim.yaml, through `bench.cli.main` in-process."""

from __future__ import annotations

import json
import shutil
from datetime import date
from pathlib import Path

import h5py
import pytest

from bench.cli import main
from bench.config import load_config
from bench.errors import InputError
from bench.identity import MAX_IDENTITY_CHARS, default_station, parse_iso_date
from bench.record import layout, read_run_summary
from bench.runner.operator import Operator
from bench.runner.unit_identity import ACCEPT_OPTION, overdue_calibrations
from tests.conftest import ROOT, SIM_CONFIG, write_procedure

SESSIONS = sorted((ROOT / "tests" / "sessions").glob("*.h5"))
PAST = "2001-01-31"
"""A calibration due date long past: overdue whenever the tests run."""
FUTURE = "2999-12-31"


@pytest.fixture(autouse=True)
def wide_terminal(monkeypatch: pytest.MonkeyPatch) -> None:
    """Rich tables as wide as needed: no value of the inspect output is wrapped."""
    monkeypatch.setenv("COLUMNS", "250")


def short_procedure(tmp_path: Path, requires: str = "") -> Path:
    """A 1-s procedure on the board; ``requires`` is inserted as a top-level line (line 4)."""
    path = write_procedure(tmp_path / "short.yaml", "  - wait: 1 s\n")
    if requires:
        lines = path.read_text().splitlines(keepends=True)
        lines.insert(3, requires + "\n")
        path.write_text("".join(lines))
    return path


def lab_config(tmp_path: Path, board: str = "", top: str = "") -> Path:
    """configs/sim.yaml with ``board`` lines added to the acs_board instrument and ``top`` lines
    after ``name:`` (sensor model paths made absolute)."""
    text = SIM_CONFIG.read_text().replace("sensor_model: sensors/", f"sensor_model: {SIM_CONFIG.parent}/sensors/")
    text = text.replace("    driver: acs_board\n", f"    driver: acs_board\n{board}", 1)
    text = text.replace("name: simulated-lab\n", f"name: simulated-lab\n{top}", 1)
    path = tmp_path / "lab.yaml"
    path.write_text(text)
    return path


def line_of(path: Path, needle: str) -> int:
    """1-based number of the first line of ``path`` containing ``needle``."""
    return next(i for i, line in enumerate(path.read_text().splitlines(), 1) if needle in line)


def run(tmp_path: Path, procedure: Path, config: Path, *options: str) -> int:
    return main(["run", str(procedure), "--config", str(config), "--runs-dir", str(tmp_path / "runs"), *options])


def only_run_file(tmp_path: Path) -> Path:
    (path,) = (tmp_path / "runs").glob("*.h5")
    return path


def calibration_events(path: Path) -> list[dict]:
    s = read_run_summary(path)
    return [json.loads(e.message) for e in s.events if e.kind == layout.EVENT_OPERATOR and e.source == layout.SOURCE_CALIBRATION]


# ---- unit and station ---------------------------------------------------------------------------
def test_unit_part_revision_station_recorded_and_inspected(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    proc = short_procedure(tmp_path)
    config = lab_config(tmp_path, top="station: tvac-bay-2\n")
    assert run(tmp_path, proc, config, "--unit", "SN12", "--part", "ACS-IMU-100", "--revision", "C") == 0
    path = only_run_file(tmp_path)
    s = read_run_summary(path)
    assert s.identity == {layout.ATTR_UNIT_SERIAL: "SN12", layout.ATTR_UNIT_PART: "ACS-IMU-100",
                          layout.ATTR_UNIT_REVISION: "C", layout.ATTR_STATION: "tvac-bay-2"}
    capsys.readouterr()
    assert main(["inspect", str(path)]) == 0
    out = capsys.readouterr().out
    assert "SN12, part ACS-IMU-100, revision C" in out
    assert "tvac-bay-2" in out


def test_station_option_overrides_config_and_host_name_is_the_default(tmp_path: Path) -> None:
    proc = short_procedure(tmp_path)
    assert run(tmp_path / "a", proc, lab_config(tmp_path, top="station: tvac-bay-2\n"), "--station", "rate-table-1") == 0
    assert read_run_summary(only_run_file(tmp_path / "a")).identity[layout.ATTR_STATION] == "rate-table-1"
    assert run(tmp_path / "b", proc, SIM_CONFIG) == 0
    identity = read_run_summary(only_run_file(tmp_path / "b")).identity
    assert identity[layout.ATTR_STATION] == default_station() != ""
    assert identity[layout.ATTR_UNIT_SERIAL] == ""  # no --unit: nothing claimed


@pytest.mark.parametrize(("option", "value", "says"), [
    ("--unit", "", "must not be empty"),
    ("--unit", "SN\x0712", "control or non-printable character"),
    ("--part", "P" * (MAX_IDENTITY_CHARS + 1), f"at most {MAX_IDENTITY_CHARS}"),
    ("--revision", "B\n", "control or non-printable character"),
    ("--station", " bay", "leading or trailing white space"),
])
def test_bad_identity_option_is_one_located_line(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                 option: str, value: str, says: str) -> None:
    options = [option, value] if option == "--unit" else ["--unit", "SN12", option, value]
    assert run(tmp_path, short_procedure(tmp_path), SIM_CONFIG, *options) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"{option}: ") and says in err, err
    assert not (tmp_path / "runs").exists()


def test_identity_text_of_exactly_64_characters_is_accepted(tmp_path: Path) -> None:
    serial = "S" * MAX_IDENTITY_CHARS
    assert run(tmp_path, short_procedure(tmp_path), SIM_CONFIG, "--unit", serial) == 0
    assert read_run_summary(only_run_file(tmp_path)).identity[layout.ATTR_UNIT_SERIAL] == serial


# ---- a procedure that requires a unit -----------------------------------------------------------
def test_procedure_requiring_a_unit_refuses_to_run_without_one(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    proc = short_procedure(tmp_path, "requires: {unit: true}")
    assert run(tmp_path, proc, SIM_CONFIG) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"{proc}:4:12: requires.unit: ") and "--unit" in err, err
    assert not (tmp_path / "runs").exists()  # refused before the run file
    assert main(["validate", str(proc), "--config", str(SIM_CONFIG)]) == 0
    assert main(["plan", str(proc), "--config", str(SIM_CONFIG)]) == 0
    assert run(tmp_path, proc, SIM_CONFIG, "--unit", "SN12") == 0
    assert read_run_summary(only_run_file(tmp_path)).identity[layout.ATTR_UNIT_SERIAL] == "SN12"


def test_requires_is_validated(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    proc = short_procedure(tmp_path, "requires: {unit: yes please, fixture: true}")
    assert main(["validate", str(proc)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 2
    assert lines[0].startswith(f"{proc}:4:18: unit: expected bool"), lines
    assert lines[1].startswith(f"{proc}:4:30: fixture: unknown field in requires"), lines


def test_requirement_of_a_called_procedure_counts(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    sub = short_procedure(tmp_path, "requires: {unit: true}")
    main_proc = write_procedure(tmp_path / "outer.yaml", f"  - call: {{procedure: {sub.name}}}\n")
    assert run(tmp_path, main_proc, SIM_CONFIG) == 2
    assert capsys.readouterr().err.startswith(f"{sub}:4:12: requires.unit: ")


# ---- instrument identity and calibration --------------------------------------------------------
def test_config_identity_recorded_next_to_reported_and_shown(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = lab_config(tmp_path, f"    serial: ACS-0042\n    firmware: '1.4.2'\n    calibration_due: {FUTURE}\n")
    assert run(tmp_path, short_procedure(tmp_path), config) == 0
    path = only_run_file(tmp_path)
    board = read_run_summary(path).instrument_identity["acs_board"]
    assert (board.serial, board.config_serial) == ("SIM-0001", "ACS-0042")  # reported by the simulator / the lab's
    assert (board.firmware, board.config_firmware) == ("sim-0.1.0", "1.4.2")
    assert board.calibration_due == FUTURE and not board.calibration_overdue
    assert calibration_events(path) == []
    capsys.readouterr()
    assert main(["inspect", str(path)]) == 0
    out = capsys.readouterr().out
    assert "SIM-0001 / ACS-0042" in out and "sim-0.1.0 / 1.4.2" in out and FUTURE in out
    assert "OVERDUE" not in out


def test_overdue_calibration_refused_without_confirmation(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = lab_config(tmp_path, f"    calibration_due: {PAST}\n")
    answers = tmp_path / "answers.yaml"
    answers.write_text("mount_z: yes\n")  # an answers file that does not answer this
    for extra in ([], ["--answers", str(answers)]):
        assert run(tmp_path, short_procedure(tmp_path), config, *extra) == 2
        err = capsys.readouterr().err
        line = line_of(config, "calibration_due")
        assert err.count("\n") == 1 and err.startswith(f"{config}:{line}:22: calibration_due: acs_board: "), err
        assert PAST in err and ACCEPT_OPTION in err
    assert not (tmp_path / "runs").exists()


def test_overdue_calibration_accepted_is_recorded_as_operator_event(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = lab_config(tmp_path, f"    calibration_due: {PAST}\n")
    assert run(tmp_path, short_procedure(tmp_path), config, ACCEPT_OPTION, "--operator", "alice") == 0
    path = only_run_file(tmp_path)
    (event,) = calibration_events(path)
    assert event["instrument"] == "acs_board" and event["calibration_due"] == PAST
    assert (event["answer"], event["source"], event["operator"]) == ("yes", ACCEPT_OPTION, "alice")
    s = read_run_summary(path)
    assert s.status == layout.STATUS_COMPLETED
    board = s.instrument_identity["acs_board"]
    assert board.calibration_overdue and "alice" in board.overdue_confirmation
    capsys.readouterr()
    assert main(["inspect", str(path)]) == 0
    assert f"{PAST} OVERDUE" in capsys.readouterr().out


@pytest.mark.parametrize(("answer", "code", "status"), [
    ("yes", 0, layout.STATUS_COMPLETED), ("no", 1, layout.STATUS_ABORTED), ("maybe", 1, layout.STATUS_ABORTED),
])
def test_overdue_calibration_asked_at_the_terminal(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                   answer: str, code: int, status: str) -> None:
    asked: list[str] = []

    class Person:
        """The operator at the terminal (bench.runner.operator.Asker): answers every question."""

        def show(self, text: str) -> None:
            asked.append(text)

        def read_line(self, timeout_s: float) -> str:
            return answer

    monkeypatch.setattr(Operator, "terminal", staticmethod(lambda: Person()))
    config = lab_config(tmp_path, f"    calibration_due: {PAST}\n")
    assert run(tmp_path, short_procedure(tmp_path), config, "--sim") == code  # a dry-run asks too
    assert len(asked) == 1 and "acs_board" in asked[0] and PAST in asked[0] and asked[0].endswith("[yes/no]")
    path = only_run_file(tmp_path)
    (event,) = calibration_events(path)
    assert (event["answer"], event["source"]) == (answer, "operator")
    s = read_run_summary(path)
    assert s.status == status
    if answer != "yes":
        assert "overdue" in s.abort_reason and not s.steps  # nothing ran
    # the catalogue heard the end too (not left `running` until the next query or rebuild)
    from bench.catalog.store import open_catalog, resolve_url
    from bench.catalog.query import RunFilter, select_runs

    with open_catalog(resolve_url(None, tmp_path / "runs"), create=False) as cat:
        (row,) = cat.select(select_runs(RunFilter()))
    assert row["status"] == status


def test_overdue_is_strictly_after_the_due_date() -> None:
    config = load_config(SIM_CONFIG)
    config.instruments["acs_board"].calibration_due = date(2026, 3, 31)
    assert overdue_calibrations(config, ["acs_board"], date(2026, 3, 31)) == []  # due today: still in calibration
    (o,) = overdue_calibrations(config, ["acs_board", "tvac"], date(2026, 4, 1))
    assert (o.instrument, o.due) == ("acs_board", date(2026, 3, 31))


@pytest.mark.parametrize(("value", "located"), [
    ("31.12.2026", ":22: calibration_due: expected a date YYYY-MM-DD"),
    ("2026-1-5", ":22: calibration_due: expected a date YYYY-MM-DD"),
    ("2026-02-30", ":22: "),  # looks like a YAML date: the YAML reader locates it
    ("[2026, 1, 5]", ":22: calibration_due: expected a date YYYY-MM-DD"),
])
def test_bad_calibration_date_is_located(tmp_path: Path, capsys: pytest.CaptureFixture[str], value: str, located: str) -> None:
    config = lab_config(tmp_path, f"    calibration_due: {value}\n")
    assert run(tmp_path, short_procedure(tmp_path), config, ACCEPT_OPTION) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"{config}:{line_of(config, 'calibration_due')}{located}"), err
    assert "Traceback" not in err


@pytest.mark.parametrize(("board", "top", "key"), [
    ("    serial: ''\n", "", "serial"),
    ("    firmware: 142\n", "", "firmware"),
    ("", "station: \"bay\\t2\"\n", "station"),
])
def test_bad_config_identity_is_located(tmp_path: Path, board: str, top: str, key: str) -> None:
    config = lab_config(tmp_path, board, top)
    with pytest.raises(InputError) as exc:
        load_config(config)
    assert exc.value.one_line().startswith(f"{config}:{line_of(config, key + ':')}:"), exc.value.one_line()
    assert exc.value.field == key


def test_iso_date_parser_takes_only_calendar_dates() -> None:
    assert parse_iso_date("2027-03-31", None, "calibration_due") == date(2027, 3, 31)
    for bad in ("2027-02-29", "2027-3-31", "20270331", "2027-03-31T00:00", 20270331):
        with pytest.raises(InputError):
            parse_iso_date(bad, None, "calibration_due")


# ---- older run files ----------------------------------------------------------------------------
@pytest.mark.parametrize("session", SESSIONS, ids=lambda p: p.stem)
def test_older_run_files_inspect_with_empty_identity(tmp_path: Path, capsys: pytest.CaptureFixture[str], session: Path) -> None:
    old = tmp_path / session.name
    shutil.copy(session, old)
    with h5py.File(old, "r+") as f:  # as written before issue 17, whenever the session was recorded
        for key in layout.IDENTITY_ATTRS:
            f.attrs.pop(key, None)
        for g in f[layout.INSTRUMENTS].values():
            for key in layout.INSTRUMENT_CONFIG_ATTRS:
                g.attrs.pop(key, None)
    s = read_run_summary(old)
    assert s.identity == {key: "" for key in layout.IDENTITY_ATTRS}
    assert s.instrument_identity and all(
        (i.config_serial, i.config_firmware, i.calibration_due, i.calibration_overdue) == ("", "", "", False)
        for i in s.instrument_identity.values())
    assert main(["inspect", str(old)]) == 0
    out = capsys.readouterr().out
    assert "unit" in out and "station" in out and "Instrument identity" not in out

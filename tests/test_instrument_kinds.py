"""Instrument kinds (docs/instruments.md): one record per kind found by entry point, no core module
naming a kind, kinds' config sections typed and located, and a lab that names its instruments as it
likes (a board ``imu``, a chamber ``chamber1``, two loggers) runs, reports and diagnoses.

Nothing here lists the kinds: they come from the registry, so a kind a lab installs is checked too.
"""

from __future__ import annotations

import ast
import json
from pathlib import Path

import pytest

from bench.kinds import registry
from tests.conftest import ROOT, SIM_CONFIG, run_cli

KINDS = registry.kinds()


# ---- discovery ----------------------------------------------------------------------------------
def test_instruments_kinds_lists_every_installed_kind_with_its_package():
    r = run_cli("instruments", "kinds", "--json")
    assert r.returncode == 0, r.stderr
    listed = json.loads(r.stdout)
    assert list(listed["kinds"]) == list(KINDS) and listed["not_loaded"] == {}
    for name, k in KINDS.items():
        assert listed["kinds"][name]["package"] == k.package
        assert listed["kinds"][name]["steps"] == [d.type for d in k.steps]
    text = run_cli("instruments", "kinds")
    assert text.returncode == 0 and all(f"{n} ({k.package})" in text.stdout for n, k in KINDS.items())


def test_a_kind_that_cannot_be_loaded_is_named_and_the_others_still_work(monkeypatch):
    """A broken plug-in (an import error, a record that is no Kind, a name taken twice) is left out
    and said why; every message naming the installed kinds says it too."""
    import importlib.metadata as md

    real = md.entry_points(group=registry.GROUP)
    fake = [*real,
            md.EntryPoint("broken", "no_such_module_anywhere:KIND", registry.GROUP),
            md.EntryPoint("notakind", "json:dumps", registry.GROUP),
            md.EntryPoint(next(iter(KINDS)), f"{next(iter(KINDS.values())).__module__}:KIND" if False else "bench.kinds.tvac:KIND",
                          registry.GROUP)]
    monkeypatch.setattr(md, "entry_points", lambda group=None: [e for e in fake if e.group == group])
    reg = registry.discover()
    assert set(reg.kinds) == set(KINDS)
    why = "\n".join(f"{k}: {v}" for k, v in reg.problems.items())
    assert "broken" in why and "ModuleNotFoundError" in why
    assert "notakind" in why and "not a bench.kinds.Kind" in why
    assert "must be the same" in why or "already declared" in why
    registry.set_registry(reg)
    try:
        assert "not loaded: " in registry.known()
    finally:
        registry.set_registry(None)


# ---- no core module names a kind -----------------------------------------------------------------
def _code_strings(path: Path) -> list[tuple[int, str]]:
    """String constants of a module that are not docstrings (line, value)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    docstrings = {id(n.body[0].value) for n in ast.walk(tree)
                  if isinstance(n, (ast.Module, ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) and n.body
                  and isinstance(n.body[0], ast.Expr) and isinstance(n.body[0].value, ast.Constant)}
    return [(n.lineno, n.value) for n in ast.walk(tree)
            if isinstance(n, ast.Constant) and isinstance(n.value, str) and id(n) not in docstrings]


def test_no_core_module_names_a_kind():
    """Outside a kind's own package (``bench/kinds/NAME/``), no code compares with, indexes by or
    defaults to a kind's name: tables keyed by kind are gone (docs and messages may show examples)."""
    names = set(KINDS) | {k.standard_name for k in KINDS.values() if k.standard_name}
    offenders = []
    for path in sorted((ROOT / "bench").rglob("*.py")):
        rel = path.relative_to(ROOT)
        if rel.parts[:2] == ("bench", "kinds") and len(rel.parts) > 3:
            continue  # a kind's own package names itself
        if rel == Path("bench/sessions.py"):
            continue  # its `kind` is a scenario of the synthetic sessions ('tvac': a table in a chamber), no instrument
        offenders += [f"{rel}:{line}: {value!r}" for line, value in _code_strings(path) if value in names]
    assert not offenders, "\n".join(offenders)



def _literal_kind_names(path: Path, names: set[str]) -> list[tuple[int, set[str]]]:
    """Tuple, list, set and dict literals of a module with the kind names they hold (line, names)."""
    found = []
    for n in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(n, (ast.Tuple, ast.List, ast.Set)):
            elts = n.elts
        elif isinstance(n, ast.Dict):
            elts = [k for k in n.keys if k is not None] + list(n.values)
        else:
            continue
        held = {e.value for e in elts if isinstance(e, ast.Constant) and e.value in names}
        if held:
            found.append((n.lineno, held))
    return found


def test_no_test_lists_the_kinds():
    """No test spells out the kinds bench ships (as kinds or by their standard instrument names): a
    test that did would skip a kind a lab installs. Each built-in kind's names are counted once."""
    ours = [k for k in KINDS.values() if k.package == "bench"]
    assert len(ours) >= 2
    names_of = {k.name: {k.name, k.standard_name} - {None} for k in ours}
    files = sorted((ROOT / "tests").rglob("*.py")) + sorted((ROOT / "examples").glob("*/tests/*.py"))
    offenders = []
    for path in files:
        for line, held in _literal_kind_names(path, set().union(*names_of.values())):
            if all(names & held for names in names_of.values()):
                offenders.append(f"{path.relative_to(ROOT)}:{line}: {sorted(held)}")
    assert not offenders, "take the kinds from bench.kinds.registry:\n" + "\n".join(offenders)

# ---- config sections -----------------------------------------------------------------------------
def _load(tmp_path: Path, body: str):
    from bench.config import load_config

    p = tmp_path / "lab.yaml"
    p.write_text("schema: bench-config/1\nname: t\nmode: hardware\ninstruments:\n" + body)
    return p, lambda: load_config(p)


def test_an_unknown_driver_names_the_installed_kinds(tmp_path):
    from bench.errors import InputErrors

    p, load = _load(tmp_path, "  psu9:\n    driver: keithley_2230\n    port: /dev/null\n")
    with pytest.raises(InputErrors) as info:
        load()
    text = info.value.one_line() if hasattr(info.value, "one_line") else str(info.value)
    assert f"{p}:6:13" in text and "unknown driver 'keithley_2230'" in text
    assert all(name in text for name in KINDS) and "bench instruments kinds" in text


@pytest.mark.parametrize("kind", [k for k in KINDS.values() if k.example], ids=lambda k: k.name)
def test_each_kind_reads_its_own_keys_and_refuses_another_s(kind, tmp_path):
    """A key of no kind's section is refused where it is written, listing the keys this kind takes."""
    from bench.errors import InputErrors

    body = "".join(f"    {line}\n" for line in kind.example.strip().splitlines())
    _, load = _load(tmp_path, "  it:\n" + body)
    load()
    _, load = _load(tmp_path, "  it:\n" + body + "    wobble_factor: 3\n")
    with pytest.raises(InputErrors) as info:
        load()
    (err,) = info.value.errors
    assert err.field == "wobble_factor" and "unknown field in instrument 'it'" in err.message
    assert "driver" in err.message and "port" in err.message  # what every instrument takes is listed with the kind's


def test_a_kind_s_own_required_key_is_located(tmp_path):
    """The chamber's section needs its gauge's port: said at the instrument, in its own words."""
    from bench.errors import InputErrors

    chamber = next(k for k in KINDS.values() if k.envelope is not None)
    _, load = _load(tmp_path, f"  chamber1:\n    driver: {chamber.name}\n    port: modbus-tcp://10.0.0.5:502\n")
    with pytest.raises(InputErrors) as info:
        load()
    assert [(e.field, e.location.line) for e in info.value.errors] == [("gauge_port", 6)]  # at the chamber's section


# ---- by kind, never by name ----------------------------------------------------------------------
RENAMED = {"acs_board": "imu", "tvac": "chamber1", "rate_table": "turntable", "thermocouples": "logger1"}
"""configs/sim.yaml's instruments as another lab names them (a second logger is added)."""

PROCEDURE = """\
schema: bench-procedure/1
name: renamed_lab
instruments: [imu, chamber1, turntable, logger1, logger2]
steps:
  - set_temperature: {instrument: chamber1, set_point: 25 degC}
  - power: {instrument: imu, on: true}
  - configure: {instrument: imu, odr: 50 Hz}
  - record: {instrument: imu, duration: 120 s, window: still}
  - table_rate: {instrument: turntable, rate: 2 deg/s, settle: 2 s}
  - record: {instrument: imu, duration: 120 s, window: turning}
  - table_stop: turntable
  - check: {signal: imu.gyro.z, statistic: mean, window: turning, min: 1.5 deg/s, max: 2.5 deg/s}
  - check: {signal: logger2.ch101, statistic: mean, window: still, min: 10 degC, max: 30 degC}
  - check: {signal: chamber1.air_temp, statistic: max, window: turning, max: 30 degC}
"""


def _renamed_config(tmp_path: Path) -> Path:
    import yaml

    data = yaml.safe_load(SIM_CONFIG.read_text())
    inst = data["instruments"]
    out = {RENAMED.get(n, n): v for n, v in inst.items() if n in RENAMED}
    out["logger2"] = json.loads(json.dumps(inst["thermocouples"]))
    out["logger2"]["sim"]["serial"] = "SIM-0004"
    out["chamber1"]["sim"].pop("modbus_port", None)
    data["instruments"] = out
    for name in ("imu",):
        model = out[name]["sim"].get("sensor_model")
        if model:
            out[name]["sim"]["sensor_model"] = str(SIM_CONFIG.parent / model)
    path = tmp_path / "renamed.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def test_a_lab_naming_its_board_imu_and_its_chamber_chamber1_runs_reports_and_diagnoses(tmp_path):
    config = _renamed_config(tmp_path)
    proc = tmp_path / "renamed_lab.yaml"
    proc.write_text(PROCEDURE)
    r = run_cli("run", str(proc), "--config", str(config), "--sim", "--runs-dir", str(tmp_path / "runs"), timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    (run,) = sorted((tmp_path / "runs").glob("*.h5"))

    from bench.analysis.dataset import load_dataset
    from bench.record.reader import read_run_summary
    from bench.report.run_report import load_run_data

    summary = read_run_summary(run)
    data = load_run_data(run, summary)
    labels = [s.label for s in data.temperatures]
    assert "chamber air" in labels and "logger1: thermocouple ch101" in labels and "logger2: thermocouple ch101" in labels
    assert any(s.label == "rate table rate" for s in data.reference) and data.board == "imu"
    ds = load_dataset(run)  # the sensor stream by kind and role, the chamber's and the table's monitors onto it
    for column in ("gyro_z_dps", "chamber_temp_c", "pressure_torr", "ref_rate_z_dps", "table_angle_deg"):
        assert column in ds, column
    import numpy as np

    ref, gyro = np.asarray(ds["ref_rate_z_dps"]), np.asarray(ds["gyro_z_dps"])
    turning, still = ref > 1.99, np.abs(ref) < 1e-9
    assert turning.any() and still.any()
    assert abs(float(gyro[turning].mean() - gyro[still].mean()) - 2.0) < 0.05  # the table's rate reaches the analysis

    report = run_cli("report", str(run), "-o", str(tmp_path / "report.html"), timeout=300)
    assert report.returncode == 0, report.stdout + report.stderr
    html = (tmp_path / "report.html").read_text()
    assert "no sensor data" not in html and "imu" in html
    diag = run_cli("diagnose", str(run), "--json", timeout=300)
    assert diag.returncode in (0, 1), diag.stdout + diag.stderr
    assert "no sensor stream" not in diag.stderr and json.loads(diag.stdout)

"""Gyro compensation (NPSAT1 Eq. 2) from calibration files, in the board driver and the run file."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml

from bench.cli import main
from bench.config import load_config
from bench.errors import InputError
from bench.model.compensation import load_compensation
from tests.conftest import ROOT, SIM_CONFIG

SIMPLE_POLY = [-1.150e-1, -7.561e-3, -1.124e-4]  # configs/sensors/acs_board_simple.yaml gyro bias vs °C


def thermal_file(path: Path, poly: list[float]) -> Path:
    path.write_text(yaml.safe_dump({"schema": "bench-calibration/1", "method": "thermal",
                                    "axes": {a: {"coefficients": poly} for a in "xyz"}}))
    return path


def test_apply_inverts_eq_1_with_table_15_terms():
    comp = load_compensation([ROOT / "configs" / "sensors" / "npsat1_qrs11_ground.yaml"])
    assert np.any(comp.m) and np.any(comp.b_cons_dps) and comp.in_run_poly_degc is not None
    rng = np.random.default_rng(4)
    omega = rng.uniform(-10, 10, (500, 3))
    temp = rng.uniform(-29, 66, 500)
    poly = np.stack([np.polynomial.polynomial.polyval(temp, c) for c in comp.in_run_poly_degc], axis=1)
    output = omega + (comp.m @ omega.T).T + comp.b_cons_dps + poly  # NPSAT1 Eq. 1 without noise
    assert np.allclose(comp.apply(output, temp), omega, atol=1e-12)


def test_files_merge_later_terms_override(tmp_path: Path):
    rt = tmp_path / "rt.yaml"
    rt.write_text(yaml.safe_dump({"method": "rate-transfer", "b_cons_dps": {"x": 0.01, "y": 0.02, "z": 0.03},
                                  "M": [[0.001, 0, 0], [0, -0.004, 0], None]}))
    comp = load_compensation([thermal_file(tmp_path / "t.yaml", [0.5, 0.01]), rt])
    assert comp.in_run_poly_degc == [[0.5, 0.01]] * 3
    assert list(comp.b_cons_dps) == [0.01, 0.02, 0.03] and comp.m[1, 1] == -0.004 and not comp.m[2].any()
    out = comp.apply(np.array([[0.5 + 0.01 * 20 + 0.01, 0.5 + 0.2 + 0.02, 0.5 + 0.2 + 0.03]]), np.array([20.0]))
    assert np.allclose(out, 0.0)


@pytest.mark.parametrize("text, says", [
    ("method: noise\n", "expected a thermal, rate-transfer or six-position calibration"),
    ("method: thermal\naxes: {x: {coefficients: [1]}}\n", "incomplete gyro compensation"),
    ("method: rate-transfer\nb_cons_dps: {x: 0, y: 0, z: 0}\nM: [[1, 2]]\n", "incomplete gyro compensation"),
])
def test_bad_calibration_files_are_located(tmp_path: Path, text, says):
    p = tmp_path / "c.yaml"
    p.write_text(text)
    with pytest.raises(InputError, match=says) as info:
        load_compensation([p])
    assert str(p) in str(info.value)


def config_with(tmp_path: Path, instrument: str, files: str) -> Path:
    text = SIM_CONFIG.read_text().replace("sensor_model: sensors/", f"sensor_model: {SIM_CONFIG.parent}/sensors/")
    anchor = f"  {instrument}:\n"
    text = text.replace(anchor, f"{anchor}    calibration: {files}\n", 1)
    p = tmp_path / "cfg.yaml"
    p.write_text(text)
    return p


def test_config_refuses_calibration_on_other_instruments(tmp_path: Path):
    thermal_file(tmp_path / "t.yaml", SIMPLE_POLY)
    with pytest.raises(InputError, match="unknown field in instrument .* calibration|calibration.*unknown field"):
        load_config(config_with(tmp_path, "tvac", "t.yaml"))
    with pytest.raises(InputError, match="not found|cannot"):
        load_config(config_with(tmp_path, "acs_board", "missing.yaml"))


def test_dry_run_records_compensated_rates_next_to_raw(tmp_path: Path):
    thermal_file(tmp_path / "t.yaml", SIMPLE_POLY)
    cfg = config_with(tmp_path, "acs_board", "[t.yaml]")
    assert main(["run", str(ROOT / "procedures" / "startup_profile.yaml"), "--config", str(cfg), "--runs-dir", str(tmp_path / "runs")]) == 0
    (path,) = (tmp_path / "runs").glob("*.h5")
    with h5py.File(path, "r") as f:
        raw = f["streams/acs_board/gyro"][:]
        comp = f["streams/acs_board/gyro_comp"][:]
        assert f["streams/acs_board/gyro_comp"].attrs["units"] == "deg/s"
        assert "NPSAT1 Eq. 2 (b_in-run)" in f["instruments/acs_board"].attrs["compensation"]
    settled = slice(len(raw) // 2, None)  # after the warm-up transient
    assert np.all(np.abs(raw[settled].mean(axis=0)) > 0.3)  # the ~20 °C bias of the model
    # left: Earth rate (≤ 0.0042 deg/s) and the tail of the warm-up
    assert np.all(np.abs(comp[settled].mean(axis=0)) < 0.006)

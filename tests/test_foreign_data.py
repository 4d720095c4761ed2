"""Foreign HDF5/netCDF-4 files read through a column mapping (bench/analysis/foreign.py, docs/analysis.md).

Synthetic files are made here with h5py in the layouts other programs write (a 2-D variable with a
column slice, separate 1-D variables, units attributes as bytes or str, a time variable, a
``sampling_rate`` attribute); the real logs of scikit-diveMove (tests/realdata.py) check the whole
path on measured data.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import h5py
import numpy as np
import pytest

from bench.analysis.dataset import load_dataset
from bench.analysis.foreign import conversion, dataset_from_foreign, load_data, parse_columns, parse_mapping
from bench.errors import InputError
from tests.cli_output import one_error_line
from tests.conftest import ROOT, run_cli

RAD = 180.0 / math.pi
G0 = 9.80665


def make_h5(path: Path, variables: dict, attrs: dict | None = None) -> Path:
    """Write ``variables`` (name -> array, or (array, {attr: value})) to HDF5 file ``path``."""
    with h5py.File(path, "w") as f:
        for name, spec in variables.items():
            data, vattrs = spec if isinstance(spec, tuple) else (spec, {})
            ds = f.create_dataset(name, data=np.asarray(data))
            for k, v in vattrs.items():
                ds.attrs[k] = v
        for k, v in (attrs or {}).items():
            f.attrs[k] = v
    return path


def phone_like(path: Path, n: int = 200) -> Path:
    """Like samsung_galaxy_s5.nc: angular_velocity (n×6, rad/s as bytes; columns 3-5 'measured'),
    acceleration (n×3, m/s2), an index 'timestamp' without units, sampling_rate [10] Hz."""
    gyro = np.zeros((n, 6))
    gyro[:, 0:3] = 5.0            # the "output" columns: must not be picked by [3:6]
    gyro[:, 3] = 1.0              # 1 rad/s
    gyro[:, 4] = -0.5
    gyro[:, 5] = np.linspace(0, 1e-3, n)
    acc = np.tile([0.0, 0.0, G0], (n, 1))
    rate = {"sampling_rate": np.array([10]), "sampling_rate_units": np.bytes_(b"Hz")}
    return make_h5(path, {
        "angular_velocity": (gyro, {"units": np.bytes_(b"rad/s"), **rate}),
        "acceleration": (acc, {"units": np.bytes_(b"m/s2"), **rate}),
        "timestamp": np.arange(n, dtype=np.int64),
    })


def bench_in_process(capsys, *args: str):
    """``bench ARGS`` through :func:`bench.cli.main` in this process (the same argument parsing and
    error reporting as the command, without a Python start-up per case)."""
    from subprocess import CompletedProcess

    from bench.cli import main

    capsys.readouterr()
    code = main(list(args))
    out = capsys.readouterr()
    return CompletedProcess(args, code, out.out, out.err)


# ---- mapping syntax and units --------------------------------------------------------------------
def test_column_ranges_parse_without_eval():
    assert parse_columns("3:6") == (3, 6)
    assert parse_columns("0") == (0, 1)
    assert parse_columns(":3") == (0, 3)
    assert parse_columns("3:") == (3, -1)
    for bad in ("3:6:1", "-1", "6:3", "a", "__import__('os')", "1+1", "3:3"):
        with pytest.raises(ValueError):
            parse_columns(bad)


@pytest.mark.parametrize("units,kind,value,expected", [
    ("rad/s", "rate", 1.0, 57.29577951308232),
    ("mrad/s", "rate", 35.73, 2.047177),
    ("deg/s", "rate", 2.0, 2.0),
    ("m/s2", "accel", G0, 1.0),
    ("m/s^2", "accel", G0, 1.0),
    ("m s-2", "accel", 2 * G0, 2.0),
    ("g", "accel", 0.5, 0.5),
    ("degC", "temp", 21.5, 21.5),
    ("C", "temp", 21.5, 21.5),
    ("K", "temp", 273.15, 0.0),
    ("Torr", "pressure", 1e-5, 1e-5),
    ("Pa", "pressure", 101325.0, 760.0),
    ("mbar", "pressure", 1013.25, 760.0),
    ("s", "time", 3.0, 3.0),
    ("ms", "time", 1500.0, 1.5),
    ("us", "time", 2e6, 2.0),
    ("rad", "angle", math.pi, 180.0),
])
def test_units_convert_to_the_dataset_units(units, kind, value, expected):
    got = conversion(units, kind).convert(np.array([value]))[0]
    assert got == pytest.approx(expected, rel=1e-6, abs=1e-12)


@pytest.mark.parametrize("units,kind", [("Hz", "rate"), ("m/s", "rate"), ("furlongs", "rate"), ("kg", "accel"),
                                        ("bananas", "temp"), ("s", "pressure"), ("deg", "time"),
                                        ("__import__('os').system('true')", "rate"), ("", "rate")])
def test_unknown_or_incompatible_units_are_refused(units, kind):
    with pytest.raises(ValueError):
        conversion(units, kind)


def test_mapping_entries_twice_or_overlapping_are_refused(tmp_path):
    with pytest.raises(InputError, match="mapped twice"):
        parse_mapping(["gyro=a", "gyro=b"])
    with pytest.raises(InputError, match="both fill gyro_x_dps"):
        parse_mapping(["gyro=a", "gyro_x=b"])
    with pytest.raises(InputError, match="unknown target 'gyroscope'"):
        parse_mapping(["gyroscope=a"])
    with pytest.raises(InputError, match="no such mapping file"):
        parse_mapping([str(tmp_path / "nothing.yaml")])


# ---- layouts ---------------------------------------------------------------------------------------
def test_2d_variable_with_column_slice_and_sampling_rate_attribute(tmp_path):
    path = phone_like(tmp_path / "phone.nc")
    ds = load_dataset(path, ["gyro=angular_velocity[3:6]", "accel=acceleration"])
    assert len(ds) == 200
    assert ds["gyro_x_dps"][0] == pytest.approx(57.29577951, abs=1e-8)  # 1 rad/s, column 3 not column 0
    assert ds["gyro_y_dps"][0] == pytest.approx(-0.5 * RAD)
    assert ds["gyro_z_dps"][-1] == pytest.approx(1e-3 * RAD)
    assert ds["accel_z_g"] == pytest.approx(np.ones(200))              # 9.80665 m/s2 -> 1 g
    assert ds["accel_x_g"] == pytest.approx(np.zeros(200))
    # time from the sampling_rate attribute: index / 10 Hz
    assert ds["time_s"][:3] == pytest.approx([0.0, 0.1, 0.2])
    assert ds.sample_rate_hz == 10.0
    assert "sampling_rate attribute of 'angular_velocity'" in ds.meta["time_source"]
    assert ds.meta["mapping"] == "gyro=angular_velocity[3:6]; accel=acceleration"


def test_separate_1d_variables_single_axes_and_units_as_str_or_bytes(tmp_path):
    n = 50
    path = make_h5(tmp_path / "axes.h5", {
        "wx": (np.full(n, 10.0), {"units": "mrad/s"}),                      # str attribute
        "wy": (np.full(n, 1.0), {"units": np.bytes_(b"deg/s")}),           # bytes attribute
        "wz": (np.full(n, 2.0), {"units": np.array([b"rad/s"])}),          # one-element array
        "ax": (np.full(n, -G0), {"units": b"m/s^2"}),
        "die_temp": (np.full(n, 300.0), {"units": b"K"}),
        "p": (np.full(n, 133.322368), {"units": "Pa"}),
        "t_ms": (np.arange(n) * 20.0, {"units": "ms"}),
    })
    ds = load_dataset(path, ["gyro_x=wx", "gyro_y=wy", "gyro_z=wz", "accel_x=ax", "temp=die_temp",
                             "pressure=p", "time=t_ms"])
    assert ds["gyro_x_dps"][0] == pytest.approx(0.01 * RAD)
    assert ds["gyro_y_dps"][0] == pytest.approx(1.0)
    assert ds["gyro_z_dps"][0] == pytest.approx(2 * RAD)
    assert ds["accel_x_g"][0] == pytest.approx(-1.0)
    assert "accel_y_g" not in ds
    assert ds["temp_c"][0] == pytest.approx(26.85)
    assert ds["pressure_torr"][0] == pytest.approx(1.0, rel=1e-6)
    assert ds["time_s"][1] == pytest.approx(0.02)
    assert ds.sample_rate_hz == pytest.approx(50.0)
    # the mapping's units win over the attribute
    ds2 = load_dataset(path, ["gyro_x=wx:deg/s", "time=t_ms:ms"])
    assert ds2["gyro_x_dps"][0] == pytest.approx(10.0)


def test_time_variable_seconds_since_origin_and_temperature_in_c(tmp_path):
    n = 100
    path = make_h5(tmp_path / "cats.nc", {
        "angular_velocity": (np.full((n, 3), 35.73), {"units": b"mrad/s", "sampling_rate": np.array([1.0])}),
        "temperature": (np.linspace(4.78, 27.77, n), {"units": b"C"}),
        "timestamp_utc": (np.arange(n, dtype=np.int64) + 60,
                          {"units": b"seconds since 2021-09-20 08:52:00", "calendar": b"proleptic_gregorian"}),
    })
    ds = load_dataset(path, ["gyro=angular_velocity", "temp=temperature", "time=timestamp_utc"])
    assert ds["time_s"][0] == 60.0 and ds["time_s"][-1] == 159.0
    assert ds.meta["time_origin"] == "2021-09-20 08:52:00"
    assert "timestamp_utc" in ds.meta["time_source"]
    assert ds["temp_c"].min() == pytest.approx(4.78) and ds["temp_c"].max() == pytest.approx(27.77)
    assert ds["gyro_x_dps"][0] == pytest.approx(2.047177, rel=1e-6)


def test_sample_rate_in_the_mapping_overrides_the_attribute(tmp_path):
    path = phone_like(tmp_path / "phone.nc", n=100)
    ds = load_dataset(path, ["gyro=angular_velocity[3:6]", "sample_rate_hz=25"])
    assert ds["time_s"][1] == pytest.approx(0.04)
    assert ds.sample_rate_hz == 25.0
    assert "sample_rate_hz of --map" in ds.meta["time_source"]


def test_netcdf_fill_values_and_packing_and_non_finite_rows_dropped(tmp_path):
    raw = np.array([100, 200, -32767, 400, 500], dtype=np.int16)
    path = make_h5(tmp_path / "packed.nc", {
        "gyro": (raw, {"units": "deg/s", "scale_factor": np.float32(0.01), "add_offset": 1.0,
                       "_FillValue": np.int16(-32767)}),
        "gyro_b": (np.array([0.0, np.nan, 0.0, 0.0, np.inf]), {"units": "deg/s"}),
    })
    ds = load_dataset(path, ["gyro_x=gyro", "gyro_y=gyro_b", "sample_rate_hz=1"])
    # rows 1 (NaN), 2 (fill value), 4 (inf) dropped; time keeps the original sample index
    assert ds["gyro_x_dps"].tolist() == pytest.approx([2.0, 5.0])
    assert ds["time_s"].tolist() == [0.0, 3.0]
    assert ds.meta["dropped_rows"] == 3.0
    assert "dropped 3 of 5 rows" in ds.meta["dropped_note"] and "first: row 1" in ds.meta["dropped_note"]
    with pytest.raises(InputError, match="no row where every mapped value is a finite number"):
        load_dataset(make_h5(tmp_path / "nan.nc", {"g": (np.full(4, np.nan), {"units": "deg/s"})}),
                     ["gyro_x=g", "sample_rate_hz=1"])


def test_yaml_mapping_file(tmp_path):
    path = phone_like(tmp_path / "phone.nc", n=64)
    mapping = tmp_path / "mapping.yaml"
    # unquoted 3:6 is the base-60 number 186 to YAML 1.1: it must still mean columns 3 to 6
    mapping.write_text("schema: bench-mapping/1\n"
                       "gyro: {variable: angular_velocity, columns: 3:6, units: rad/s}\n"
                       "accel: acceleration:m/s2\n"
                       "sample_rate_hz: 20 Hz\n"
                       "latitude_deg: 36.6\n")
    ds = load_dataset(path, [str(mapping)])
    assert ds["gyro_x_dps"][0] == pytest.approx(RAD)
    assert ds["accel_z_g"][0] == pytest.approx(1.0)
    assert ds["time_s"][1] == pytest.approx(0.05)
    assert ds.latitude_deg() == 36.6
    bad = tmp_path / "bad.yaml"
    bad.write_text("gyro: {variable: angular_velocity, columns: \"3:6\"}\ngyroscope: x\n")
    with pytest.raises(InputError) as info:
        load_dataset(path, [str(bad)])
    assert str(info.value).startswith(f"{bad}:2:1: gyroscope: unknown key")


# ---- errors through the CLI: exit 2, one located line ------------------------------------------------
@pytest.fixture
def phone(tmp_path):
    return phone_like(tmp_path / "phone.nc")


def test_cli_errors_name_the_file_and_the_mapping_entry(tmp_path, phone, capsys):
    p = str(phone)
    short = make_h5(tmp_path / "short.nc", {
        "angular_velocity": (np.zeros((10, 3)), {"units": b"rad/s"}),
        "acceleration": (np.zeros((9, 3)), {"units": b"m/s2"}),
        "temperature": np.zeros(10),
        "t": (np.array([0.0, 1, 2, 2, 3, 4, 5, 6, 7, 8]), {"units": "s"}),
    })
    s = str(short)
    binary = tmp_path / "data.bin"
    binary.write_bytes(b"\x00\x01binary\x00" * 10)
    cases = [
        ([p, "--map", "gyro=angular_velocity[3:6]:furlongs/s"],
         f"{p}: mapping entry 'gyro': units 'furlongs/s'"),
        ([p, "--map", "gyro=angular_velocity[3:6]:bananas"],
         f"{p}: mapping entry 'gyro': unknown units 'bananas'"),
        ([p, "--map", "gyro=angular_velocit[3:6]"],
         f"{p}: mapping entry 'gyro': no variable 'angular_velocit' in the file (variables: acceleration (200×3, "
         "m/s2), angular_velocity (200×6, rad/s), timestamp (200, no units))"),
        ([p, "--map", "gyro=angular_velocity[4:7]"],
         f"{p}: mapping entry 'gyro': columns [4:7] are out of range: 'angular_velocity' has 6 columns (0 to 5)"),
        ([p, "--map", "gyro=angular_velocity"],
         f"{p}: mapping entry 'gyro': needs 3 columns (gyro_x_dps, gyro_y_dps, gyro_z_dps); 'angular_velocity' has 6"),
        ([s, "--map", "gyro=angular_velocity", "--map", "accel=acceleration"],
         f"{s}: mapping entry 'accel': 'acceleration' has 9 rows but 'angular_velocity' (entry 'gyro') has 10"),
        ([s, "--map", "gyro=angular_velocity", "--map", "temp=temperature"],
         f"{s}: mapping entry 'temp': units are needed: 'temperature' has no units attribute"),
        ([s, "--map", "gyro=angular_velocity"],
         f"{s}: mapping entry 'time': no time: map a time variable"),
        ([s, "--map", "gyro=angular_velocity", "--map", "time=t"],
         f"{s}: mapping entry 'time': time must increase from sample to sample: row 3 (2.0 s) follows row 2"),
        ([s, "--map", "gyro=angular_velocity", "--map", "time=angular_velocity[0]:degC"],
         f"{s}: mapping entry 'time': units 'degC'"),
        ([str(tmp_path / "absent.nc"), "--map", "gyro=x"], f"{tmp_path / 'absent.nc'}: data file not found"),
        ([str(ROOT / "tests" / "data" / "npsat1_tables_9_11.csv"), "--map", "gyro=x"],  # a CSV: columns named
         f"{ROOT / 'tests' / 'data' / 'npsat1_tables_9_11.csv'}: mapping entry 'gyro': needs 3 columns "
         "(gyro_x_dps, gyro_y_dps, gyro_z_dps); 'x' names 1"),
        ([str(binary), "--map", "gyro=x"], f"{binary}: not an HDF5 or netCDF-4 file"),
        ([p, "--map", "gyro=angular_velocity[3:6", "--map", "sample_rate_hz=10"], "--map: 'gyro=angular_velocity[3:6'"),
    ]
    for i, (args, start) in enumerate(cases):
        # two through a real `python -m bench` process, the rest through bench.cli.main in this one
        res = run_cli("calibrate", "noise", *args) if i in (0, 5) else bench_in_process(capsys, "calibrate", "noise", *args)
        msg = one_error_line(res)
        assert msg.startswith(start), (args, msg)


def test_foreign_file_without_map_lists_its_variables(phone, tmp_path):
    for cmd in (["calibrate", "noise", str(phone)], ["diagnose", str(phone)],
                ["import", str(phone), "-o", str(tmp_path / "out.h5")]):
        msg = one_error_line(run_cli(*cmd))
        assert msg.startswith(f"{phone}: not a bench run file: to analyse another program's HDF5/netCDF-4 data pass "
                              "--map TARGET=VARIABLE[COLUMNS]:UNITS"), msg
        assert "variables: acceleration (200×3, m/s2), angular_velocity (200×6, rad/s), timestamp (200, no units)" in msg
    assert not (tmp_path / "out.h5").exists()


def test_netcdf3_file_is_refused_with_the_conversion_hint(tmp_path):
    path = tmp_path / "classic.nc"
    path.write_bytes(b"CDF\x01" + bytes(60))
    with pytest.raises(InputError, match="netCDF-3 classic file; convert it to netCDF-4"):
        dataset_from_foreign(path, ["gyro=x"])


def test_run_files_keep_working_without_map_and_refuse_one():
    session = ROOT / "tests" / "sessions" / "rate_transfer_short.h5"
    ds, notes = load_data(session)
    assert len(ds) > 0 and "gyro_x_dps" in ds and notes == []
    with pytest.raises(InputError, match="is a bench run file; it is read without --map"):
        load_data(session, ["gyro=streams/acs_board/gyro"])


def test_import_of_a_mapped_file_round_trips(tmp_path, phone):
    out = tmp_path / "run.h5"
    res = run_cli("import", str(phone), "--map", "gyro=angular_velocity[3:6]", "--map", "accel=acceleration",
                  "-o", str(out))
    assert res.returncode == 0, res.stderr
    assert f"200 rows of {phone} written to {out}" in res.stdout
    assert "time_s from sample index / 10 Hz (sampling_rate attribute of 'angular_velocity')" in res.stdout
    ds = load_dataset(out)
    direct = load_dataset(phone, ["gyro=angular_velocity[3:6]", "accel=acceleration"])
    for c in direct.columns:
        assert ds[c] == pytest.approx(direct[c]), c
    assert ds.meta["mapping"] == "gyro=angular_velocity[3:6]; accel=acceleration"
    assert ds.sample_rate_hz == 10.0
    # existing files are never overwritten
    res = run_cli("import", str(phone), "--map", "gyro=angular_velocity[3:6]", "-o", str(out))
    assert one_error_line(res).startswith(f"-o: {out} exists; choose another name or delete it")


def test_calibrate_and_diagnose_take_a_mapped_file(tmp_path):
    n = 4000
    rng = np.random.default_rng(7)
    path = make_h5(tmp_path / "static.nc", {
        "imu": (np.column_stack([0.001 + rng.normal(0, 1e-3, (n, 3)), rng.normal(0, 0.01, (n, 3))]),
                {"units": np.bytes_(b"rad/s"), "sampling_rate": np.array([100]),
                 "sampling_rate_units": np.bytes_(b"Hz")}),
        "temp": (20 + np.linspace(0, 5, n), {"units": b"C"}),
    })
    mapping = tmp_path / "m.yaml"
    mapping.write_text("gyro: imu[0:3]:rad/s\ntemp: temp\n")
    res = run_cli("calibrate", "noise", str(path), "--map", str(mapping), "--json")
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout)  # notes go to stderr, stdout stays JSON
    assert out["static_samples"] == n and out["sample_rate_hz"] == 100.0
    assert "note: " in res.stderr and "100 Hz" in res.stderr
    res = run_cli("diagnose", str(path), "--map", str(mapping), "--json")
    assert res.returncode == 0, res.stderr
    json.loads(res.stdout)


# ---- real data (scikit-diveMove's test logs, fetched and cached by tests/realdata.py) -------------------
def test_real_phone_log_noise_through_the_cli(real_log):
    path = real_log("samsung_galaxy_s5.nc")
    res = run_cli("calibrate", "noise", str(path), "--map", "gyro=angular_velocity[3:6]:rad/s", "--json")
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout)
    assert out["static_samples"] == 214800
    assert out["sample_rate_hz"] == 10.0
    assert set(out["axes"]) == {"x", "y", "z"}
    assert "sampling_rate attribute of 'angular_velocity'" in res.stderr


def test_real_cats_log_loads_in_dataset_units(real_log):
    path = real_log("cats_temperature_calib.nc")
    ds = load_dataset(path, ["gyro=angular_velocity", "accel=acceleration", "temp=temperature",
                             "time=timestamp_utc"])
    assert len(ds) == 268081
    assert ds["temp_c"].min() == pytest.approx(4.78) and ds["temp_c"].max() == pytest.approx(27.77)
    assert 4.7 <= ds["temp_c"].min() and ds["temp_c"].max() <= 27.8
    assert float(np.mean(ds["gyro_x_dps"])) == pytest.approx(35.7272 * RAD / 1000, rel=1e-4)  # 35.73 mrad/s
    assert float(np.mean(ds["gyro_x_dps"])) == pytest.approx(2.047, abs=1e-3)
    g = np.sqrt(ds["accel_x_g"] ** 2 + ds["accel_y_g"] ** 2 + ds["accel_z_g"] ** 2)
    assert float(np.median(g)) == pytest.approx(1.0, abs=0.05)  # 1.029 g: an uncalibrated accelerometer
    assert ds.meta["time_origin"] == "2021-09-20 08:52:00"
    assert ds.sample_rate_hz == pytest.approx(1.0)

"""Procedure and config loading: valid files load; every problem is one located line."""

from __future__ import annotations

import math
import textwrap

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.config import load_config
from bench.errors import InputError, InputErrors
from bench.kinds import registry
from bench.procedure import load_procedure, parse_procedure
from tests.conftest import SIM_CONFIG, STARTUP


def test_startup_profile_loads_with_units_converted():
    p = load_procedure(STARTUP)
    assert p.name == "startup_profile"
    assert [s.type for s in p.steps] == ["comment", "power", "configure", "record", "bit", "power"]
    record = p.steps[3]
    assert record.params["duration"] == pytest.approx(1800.0)  # "30 min"
    assert p.steps[2].params["odr"] == pytest.approx(100.0)
    assert p.estimated_duration_s() == pytest.approx(1800.0)


def _errors(text: str) -> list[InputError]:
    with pytest.raises(InputErrors) as info:
        parse_procedure(textwrap.dedent(text), "p.yaml")
    return info.value.errors


def test_unknown_step_type_is_located():
    errs = _errors("""\
        schema: bench-procedure/1
        name: x
        instruments: [acs_board]
        steps:
          - wait: {duration: 1 s}
          - recrod: {instrument: acs_board, duration: 1 s}
        """)
    assert len(errs) == 1
    assert errs[0].location.line == 6 and errs[0].location.column == 5
    assert "unknown step type 'recrod'" in errs[0].one_line()
    assert errs[0].one_line().startswith("p.yaml:6:5: recrod: ")


def test_every_error_reported_with_field_and_line():
    errs = _errors("""\
        schema: bench-procedure/1
        name: x
        instruments: [acs_board]
        steps:
          - record: {instrument: acs_board, duration: 30 m}
          - configure: {instrument: acs_board, odr: 5000 Hz}
          - bit: {instrument: chamber}
          - wait: {duration: 1 s, colour: red}
          - power: {instrument: acs_board, on: maybe}
        """)
    lines = [e.one_line() for e in errs]
    assert any(l.startswith("p.yaml:5:") and "duration" in l and "[length]" in l for l in lines), lines
    assert any(l.startswith("p.yaml:6:") and "odr" in l and "outside the allowed range" in l for l in lines), lines
    assert any(l.startswith("p.yaml:7:") and "'chamber'" in l for l in lines), lines
    assert any(l.startswith("p.yaml:8:") and "colour" in l and "unknown field" in l for l in lines), lines
    assert any(l.startswith("p.yaml:9:") and "on" in l and "true or false" in l for l in lines), lines
    assert len(errs) == 5


@pytest.mark.parametrize(
    "text, needle",
    [
        ("schema: bench-procedure/9\nname: x\ninstruments: []\nsteps: [{wait: {duration: 1}}]\n", "unsupported schema"),
        ("schema: bench-procedure/1\nname: x\ninstruments: []\n", "steps"),
        ("schema: bench-procedure/1\nname: x\nsteps: [{wait: {duration: 1}}]\n", "instruments"),
        ("- a\n- b\n", "mapping at top level"),
        ("schema: [unclosed\n", "not valid YAML"),
        ("schema: bench-procedure/1\nname: bad name!\ninstruments: []\nsteps: [{wait: {duration: 1}}]\n", "name"),
        ("schema: bench-procedure/1\nschema: bench-procedure/1\n", "duplicate key"),
        ("schema: bench-procedure/1\nname: x\ninstruments: []\nsteps: [{wait: {duration: '-5 s'}}]\n", "outside"),
    ],
)
def test_bad_documents_give_one_located_error(text, needle):
    with pytest.raises(InputError) as info:
        parse_procedure(text, "p.yaml")
    assert needle in str(info.value)
    assert str(info.value).startswith("p.yaml")
    assert "\n" not in info.value.one_line()


def test_python_tags_are_not_executed():
    with pytest.raises(InputError):
        parse_procedure("schema: !!python/object/apply:os.system ['echo hacked']\n", "p.yaml")


@settings(max_examples=300, deadline=None)
@given(st.text(max_size=300))
def test_loader_never_raises_anything_but_input_error(text):
    try:
        parse_procedure(text, "fuzz.yaml")
    except InputError as exc:
        assert exc.one_line().startswith("fuzz.yaml")


_step_values = st.one_of(
    st.none(), st.booleans(), st.integers(-10**6, 10**6), st.floats(allow_nan=True), st.text(max_size=20),
    st.sampled_from(["10 s", "30 min", "100 Hz", "-29 degC", "1e-5 Torr", "5 parsec", "acs_board", "Hz Hz"]),
)


@settings(max_examples=300, deadline=None)
@given(
    st.lists(
        st.dictionaries(
            st.sampled_from(["comment", "power", "configure", "record", "wait", "bit", "bogus"]),
            st.one_of(_step_values, st.dictionaries(st.sampled_from(["instrument", "on", "odr", "moving_average", "duration", "window", "expect_mask", "name", "text", "x"]), _step_values, max_size=4)),
            min_size=1, max_size=2,
        ),
        min_size=1, max_size=6,
    )
)
def test_structured_fuzz_is_valid_or_located(steps):
    import yaml

    text = yaml.safe_dump({"schema": "bench-procedure/1", "name": "fz", "instruments": ["acs_board"], "steps": steps})
    try:
        p = parse_procedure(text, "fz.yaml")
    except InputErrors as exc:
        assert all(e.location is not None and e.location.line for e in exc.errors)
    else:
        assert len(p.steps) == len(steps)


def test_sim_config_loads():
    c = load_config(SIM_CONFIG)
    inst = c.instruments["acs_board"]
    assert inst.baudrate == 115200 and inst.timeout_s == pytest.approx(0.5)
    assert c.world.latitude_deg == pytest.approx(36.4)
    assert inst.sim.settings.model.gyro_noise_density_dps_rthz == pytest.approx(0.005)


@pytest.mark.parametrize("name", ["sim.yaml", "sim_rotating_bench.yaml", "lab.example.yaml"])
def test_shipped_configs_load(name):
    c = load_config(SIM_CONFIG.parent / name)
    assert c.instruments
    if name != "sim_rotating_bench.yaml":
        ours = {k.name for k in registry.kinds().values() if k.package == "bench"}
        assert {i.driver for i in c.instruments.values()} == ours  # one instrument of each kind bench ships
    assert (c.mode == "sim") == (name == "sim.yaml")


def test_instrument_specific_fields_are_checked(tmp_path):
    bad = tmp_path / "c.yaml"
    bad.write_text(
        "schema: bench-config/1\nmode: dream\ninstruments:\n  tvac:\n    driver: tvac\n    port: modbus-tcp://x\n"
        "  thermocouples:\n    driver: thermocouple_reader\n    port: /dev/x\n    tc_type: J\n    channels: [5]\n"
        "    sim: {backend: thermocouple_reader, modbus_port: 70000}\n"
        "  stepper_bench:\n    driver: stepper_bench\n    port: /dev/y\n    sim: {backend: stepper_bench, eccentricity: {amplitude: 2}}\n"
    )
    with pytest.raises(InputErrors) as info:
        load_config(bad)
    text = "\n".join(e.one_line() for e in info.value.errors)
    for needle in ("mode", "gauge_port", "tc_type", "channels", "modbus_port", "harmonic"):
        assert needle in text, (needle, text)


def test_bad_config_is_located(tmp_path):
    bad = tmp_path / "c.yaml"
    bad.write_text(
        "schema: bench-config/1\nworld:\n  latitude: 100 deg\ninstruments:\n  acs_board:\n    driver: warp_drive\n    port: /dev/x\n    timeout: 5 kg\n"
    )
    with pytest.raises(InputErrors) as info:
        load_config(bad)
    lines = [e.one_line() for e in info.value.errors]
    assert any(":3:" in l and "latitude" in l for l in lines), lines
    assert any(":6:" in l and "warp_drive" in l for l in lines), lines
    assert any(":8:" in l and "timeout" in l for l in lines), lines


@pytest.mark.parametrize("text", ["()", "**", "[]", "1 (", "1e999 s", "nan s", ".nan"])
def test_unreadable_or_non_finite_quantities_are_input_errors(text):
    from bench.units import to_units

    with pytest.raises(InputError):
        to_units(text if text != ".nan" else float("nan"), "s")


@settings(max_examples=300, deadline=None)
@given(st.text(alphabet="0123456789.eE+-*/^() []sminHzdegCTorrkgu", max_size=20))
def test_quantity_parser_never_escapes(text):
    from bench.units import to_units

    try:
        value = to_units(text, "s")
    except InputError:
        return
    assert math.isfinite(value)

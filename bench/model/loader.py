"""Load and validate sensor model files (``configs/sensors/*.yaml``, schema ``bench-sensor-model/1``).

A model file names its model and gives its parameters; every problem (unknown key, wrong type,
wrong length, out-of-range value) is an :class:`bench.errors.InputError` located at the file, line
and column of the offending value, with the field's dotted name (``adc.bits``,
``packages.sting.bias``, ``effects[0].axis``). Several problems are raised together as
:class:`bench.errors.InputErrors`. The YAML is read with :mod:`bench.yamlsrc` (located nodes,
safe loader).

Models (``model:``):

* ``imu_simple`` — :class:`bench.model.imu_simple.ImuModelParams` (the ACS board's first model);
* ``npsat1_gyro`` — :class:`bench.model.gyro.GyroModelParams`, the NPSAT1 Eq. (1)-(3) gyro model,
  also used for the ESTCube-2 gyros (two-level calibration terms, digital output);
* ``nasa_sensor`` — one or more :class:`bench.model.accel.NasaSensorParams` packages
  (``packages: {name: {bias, sensitivity, azimuth_deg, coning_deg}}``) with ``input_unit`` and
  ``output_unit``.

Every model file may carry ``description``, ``source`` and an ``effects:`` list of extra physical
terms (``{effect: NAME, axis: x|y|z|all, params: {...}, source: TEXT}``) that
:class:`bench.model.gyro.GyroModel` hands to :func:`bench.model.effects.apply_effects`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bench.errors import InputError, InputErrors, Location
from bench.model.accel import NasaSensorParams
from bench.model.adc import AdcParams
from bench.model.digital import DigitalParams
from bench.model.gyro import AXES, OUTPUTS, POLY_VARIABLES, GyroModel, GyroModelParams
from bench.model.imu_simple import ImuModelParams
from bench.yamlsrc import Node, Source, load_yaml, parse_yaml

SCHEMA = "bench-sensor-model/1"
MODELS = ("imu_simple", "npsat1_gyro", "nasa_sensor")
EFFECT_AXES = ("x", "y", "z", "all")

_BAD = object()


# ---- value kinds ---------------------------------------------------------------------------------
def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


class _Kind:
    """How to check one value: ``check`` returns the plain value or ``_BAD`` (after recording).
    The base kind accepts any value: it marks a known field validated elsewhere (``effects``,
    ``packages``); the subclasses check."""

    def check(self, node: Node, name: str, errors: list[InputError]) -> Any:
        return node.plain()


@dataclass
class _Num(_Kind):
    lo: float | None = None
    lo_open: bool = False
    hi: float | None = None
    integer: bool = False
    nullable: bool = False

    def describe(self) -> str:
        what = "an integer" if self.integer else "a number"
        if self.lo is not None:
            what += f" {'>' if self.lo_open else '>='} {self.lo:g}"
        if self.hi is not None:
            what += f" and <= {self.hi:g}"
        return what

    def ok(self, v: Any) -> bool:
        if self.integer and not (isinstance(v, int) and not isinstance(v, bool)):
            return False
        if not _is_number(v) or not np.isfinite(v):
            return False
        if self.lo is not None and (v <= self.lo if self.lo_open else v < self.lo):
            return False
        return self.hi is None or v <= self.hi

    def check(self, node: Node, name: str, errors: list[InputError]) -> Any:
        if node.value is None and self.nullable:
            return None
        if not self.ok(node.value):
            hint = ""
            if isinstance(node.value, str):
                try:
                    float(node.value)
                    hint = " (YAML reads an exponent without a sign as text: write e.g. 1.0e+4)"
                except ValueError:
                    pass
            errors.append(InputError(f"expected {self.describe()}, got {_describe(node.value)}{hint}", node.location, name))
            return _BAD
        return float(node.value) if not self.integer else int(node.value)


@dataclass
class _Vec(_Kind):
    n: int | None
    elem: _Num = field(default_factory=_Num)

    def check(self, node: Node, name: str, errors: list[InputError]) -> Any:
        size = f"{self.n} " if self.n else ""
        if not isinstance(node.value, list) or (self.n is not None and len(node.value) != self.n) or not node.value:
            got = f"a list of {len(node.value)}" if isinstance(node.value, list) else _describe(node.value)
            errors.append(InputError(f"expected a list of {size}numbers ({self.elem.describe()}), got {got}", node.location, name))
            return _BAD
        out = []
        for i, item in enumerate(node.value):
            v = self.elem.check(item, f"{name}[{i}]", errors)
            if v is _BAD:
                return _BAD
            out.append(v)
        return out


@dataclass
class _Mat(_Kind):
    rows: int
    cols: int | None

    def check(self, node: Node, name: str, errors: list[InputError]) -> Any:
        if not isinstance(node.value, list) or len(node.value) != self.rows:
            got = f"a list of {len(node.value)}" if isinstance(node.value, list) else _describe(node.value)
            shape = f"{self.rows}×{self.cols}" if self.cols else f"{self.rows} rows of"
            errors.append(InputError(f"expected a {shape} list of lists of numbers, got {got}", node.location, name))
            return _BAD
        out = []
        for i, row in enumerate(node.value):
            v = _Vec(self.cols).check(row, f"{name}[{i}]", errors)
            if v is _BAD:
                return _BAD
            out.append(v)
        return out


@dataclass
class _Choice(_Kind):
    choices: tuple[str, ...]

    def check(self, node: Node, name: str, errors: list[InputError]) -> Any:
        if not isinstance(node.value, str) or node.value not in self.choices:
            errors.append(InputError(f"expected one of {', '.join(self.choices)}, got {_describe(node.value)}", node.location, name))
            return _BAD
        return node.value


class _Str(_Kind):
    def check(self, node: Node, name: str, errors: list[InputError]) -> Any:
        if not isinstance(node.value, str):
            errors.append(InputError(f"expected text, got {_describe(node.value)}", node.location, name))
            return _BAD
        return node.value


@dataclass
class _Map(_Kind):
    spec: dict[str, _Kind]
    what: str

    def check(self, node: Node, name: str, errors: list[InputError]) -> Any:
        return _check_mapping(node, self.spec, self.what, f"{name}.", errors)


@dataclass
class _AxisMap(_Kind):
    """Mapping axis name (x, y, z) → value of ``kind``."""

    kind: _Kind

    def check(self, node: Node, name: str, errors: list[InputError]) -> Any:
        if not isinstance(node.value, dict):
            errors.append(InputError(f"expected a mapping of axis (x, y, z) to values, got {_describe(node.value)}", node.location, name))
            return _BAD
        out = {}
        for key, child in node.value.items():
            if key not in AXES:
                errors.append(InputError(f"unknown axis {key!r} (expected x, y or z)", node.key_locations.get(key, node.location), f"{name}.{key}"))
                continue
            v = self.kind.check(child, f"{name}.{key}", errors)
            if v is not _BAD:
                out[key] = v
        return out


def _describe(value: Any) -> str:
    if isinstance(value, list):
        return f"a list of {len(value)}"
    if isinstance(value, dict):
        return "a mapping"
    if value is None:
        return "nothing"
    return f"{type(value).__name__} {value!r}"


def _check_mapping(node: Node, spec: dict[str, _Kind], what: str, prefix: str, errors: list[InputError],
                   required: tuple[str, ...] = (), skip: tuple[str, ...] = ()) -> Any:
    """Check every key of mapping ``node`` against ``spec``; unknown keys are errors. Returns the
    plain values of the good keys, or ``_BAD`` if ``node`` is not a mapping."""
    if not isinstance(node.value, dict):
        errors.append(InputError(f"{what} must be a mapping, got {_describe(node.value)}", node.location, prefix.rstrip(".") or None))
        return _BAD
    out: dict[str, Any] = {}
    for key, child in node.value.items():
        if key in skip:
            continue
        if key not in spec:
            expected = ", ".join(sorted(spec))
            errors.append(InputError(f"unknown field in {what} (expected one of: {expected})",
                                     node.key_locations.get(key, child.location), prefix + key))
            continue
        v = spec[key].check(child, prefix + key, errors)
        if v is not _BAD:
            out[key] = v
    for key in required:
        if key not in node.value:
            errors.append(InputError(f"missing required field in {what}", node.location, prefix + key))
    return out


# ---- schemas -------------------------------------------------------------------------------------
_ANY = _Num()
_NONNEG = _Num(lo=0.0)
_POS = _Num(lo=0.0, lo_open=True)

ADC_SPEC: dict[str, _Kind] = {
    "bits": _Num(lo=1, hi=32, integer=True),
    "full_scale_v": _POS,
    "r_shift_v": _ANY,
    "t_shift_v": _ANY,
    "scale_factor_v_per_dps": _POS,
    "temp_nominal_v": _Vec(3),
    "temp_nominal_c": _Vec(3),
    "temp_slope_v_per_c": _POS,
}

DIGITAL_SPEC: dict[str, _Kind] = {
    "bits": _Num(lo=2, hi=32, integer=True),
    "full_scale_dps": _POS,
    "lsb_dps": _Num(lo=0.0, lo_open=True, nullable=True),
    "moving_average_n": _Num(lo=1, hi=255, integer=True),
}

GYRO_SPEC: dict[str, _Kind] = {
    "b_cons_dps": _Vec(3),
    "run_to_run_sigma_dps": _Vec(3, _NONNEG),
    "in_run_poly": _Mat(3, None),
    "in_run_poly_variable": _Choice(POLY_VARIABLES),
    "pressure_shift_vacuum_dps": _Vec(3),
    "pressure_transition_torr": _POS,
    "pressure_reference_torr": _NONNEG,
    "misalignment_pct": _Mat(3, 3),
    "two_level_correction": _AxisMap(_Mat(3, 3)),
    "g_sensitivity_dps_per_g": _Mat(3, 3),
    "warmup_amplitude_dps": _Vec(3),
    "warmup_tau_s": _Vec(3, _POS),
    "arw_deg_rth": _Vec(3, _NONNEG),
    "bias_instability_dph": _Vec(3, _NONNEG),
    "bias_instability_tau_range_s": _Vec(2, _POS),
    "bias_instability_per_decade": _Num(lo=1, hi=20, integer=True),
    "rrw_deg_h_rth": _Vec(3, _NONNEG),
    "rate_ramp_dph_per_h": _Vec(3),
    "output": _Choice(OUTPUTS),
    "adc": _Map(ADC_SPEC, "adc"),
    "digital": _Map(DIGITAL_SPEC, "digital"),
}

IMU_SIMPLE_SPEC: dict[str, _Kind] = {
    "gyro_bias_dps": _Vec(3),
    "gyro_bias_poly_degc": _Vec(None),
    "warmup_amplitude_dps": _Vec(3),
    "warmup_settling_s": _Vec(3, _POS),
    "gyro_noise_density_dps_rthz": _NONNEG,
    "accel_bias_g": _Vec(3),
    "accel_noise_density_g_rthz": _NONNEG,
    "mag_bias_ut": _Vec(3),
    "mag_noise_rms_ut": _NONNEG,
    "lowpass_cutoff_hz": _NONNEG,
}

NASA_PACKAGE_SPEC: dict[str, _Kind] = {
    "bias": _Vec(3),
    "sensitivity": _Vec(3),
    "azimuth_deg": _Vec(3),
    "coning_deg": _Vec(3),
    "description": _Str(),
}

NASA_SPEC: dict[str, _Kind] = {
    "input_unit": _Choice(("g", "deg/s")),
    "output_unit": _Str(),
}

EFFECT_PARAM_VALUE = (int, float, str, bool, list)

COMMON_SPEC: dict[str, _Kind] = {
    "schema": _Str(),
    "model": _Choice(MODELS),
    "description": _Str(),
    "source": _Str(),
}


# ---- the spec ------------------------------------------------------------------------------------
@dataclass
class SensorModelSpec:
    """A validated model file. Exactly one of ``gyro`` / ``imu`` / ``nasa_packages`` is set,
    according to ``model``; ``effects`` is the file's ``effects:`` list as plain dicts."""

    path: Path
    model: str
    description: str = ""
    source: str = ""
    gyro: GyroModelParams | None = None
    imu: ImuModelParams | None = None
    nasa_packages: dict[str, NasaSensorParams] = field(default_factory=dict)
    nasa_input_unit: str | None = None
    nasa_output_unit: str | None = None
    effects: list[dict[str, Any]] = field(default_factory=list)
    location: Location | None = None

    def gyro_model(self, rng: np.random.Generator | None = None, output: str | None = None) -> GyroModel:
        """A stateful :class:`GyroModel` with this file's parameters and effects (``output``
        overrides the file's output path)."""
        if self.gyro is None:
            raise InputError(f"model {self.model!r} is not a gyro model (expected model: npsat1_gyro)", self.location, "model")
        params = self.gyro if output is None else _replace_output(self.gyro, output)
        return GyroModel(params, rng, self.effects)

    def nasa(self, package: str | None = None) -> NasaSensorParams:
        """The NASA package ``package`` (may be omitted when the file has exactly one)."""
        if not self.nasa_packages:
            raise InputError(f"model {self.model!r} has no NASA sensor packages", self.location, "model")
        if package is None:
            if len(self.nasa_packages) != 1:
                raise InputError(f"several packages ({', '.join(self.nasa_packages)}): name one", self.location, "packages")
            return next(iter(self.nasa_packages.values()))
        if package not in self.nasa_packages:
            raise InputError(f"no package {package!r} (have: {', '.join(self.nasa_packages)})", self.location, "packages")
        return self.nasa_packages[package]


def _replace_output(params: GyroModelParams, output: str) -> GyroModelParams:
    from bench.model.gyro import with_output

    return with_output(params, output)


def load_sensor_model(path: str | Path) -> SensorModelSpec:
    """Read and validate the model file at ``path``. Raises :class:`InputError` (one problem) or
    :class:`InputErrors` (several), each located (file:line:column) with its field name."""
    return _build(load_yaml(path, "sensor model"))


def parse_sensor_model(text: str, path: str = "<sensor model>") -> SensorModelSpec:
    """Validate model-file ``text`` (``path`` is used in messages)."""
    return _build(parse_yaml(text, path, "sensor model"))


def _build(src: Source) -> SensorModelSpec:
    errors: list[InputError] = []
    root = src.root
    top = root.value
    model_spec: dict[str, _Kind] = {}
    model = top.get("model").value if isinstance(top.get("model"), Node) else None
    if model == "npsat1_gyro":
        model_spec = GYRO_SPEC
    elif model == "imu_simple":
        model_spec = IMU_SIMPLE_SPEC
    elif model == "nasa_sensor":
        model_spec = {**NASA_SPEC, "packages": _Kind()}  # packages checked below
    skip = ("effects", "packages") if model in MODELS else tuple(k for k in top if k not in COMMON_SPEC)
    plain = _check_mapping(root, {**COMMON_SPEC, **model_spec, "effects": _Kind()}, f"sensor model ({model})", "",
                           errors, required=("schema", "model"), skip=skip)
    if plain.get("schema", SCHEMA) != SCHEMA and "schema" in top:
        errors.append(InputError(f"expected schema: {SCHEMA}", top["schema"].location, "schema"))
    spec = SensorModelSpec(path=src.path, model=str(model), description=plain.get("description", ""),
                           source=plain.get("source", ""), location=root.location)
    if "effects" in top:
        spec.effects = _effects(top["effects"], errors)
    if model == "npsat1_gyro":
        spec.gyro = _gyro_params(plain, root, errors)
    elif model == "imu_simple":
        spec.imu = ImuModelParams(**{k: v for k, v in plain.items() if k in IMU_SIMPLE_SPEC})
    elif model == "nasa_sensor":
        spec.nasa_input_unit = plain.get("input_unit")
        spec.nasa_output_unit = plain.get("output_unit")
        spec.nasa_packages = _packages(top.get("packages"), root, errors)
        if "input_unit" not in top:
            errors.append(InputError("missing required field in sensor model (nasa_sensor)", root.location, "input_unit"))
    elif "packages" in top and model in MODELS:
        errors.append(InputError("unknown field in sensor model (packages belong to model: nasa_sensor)",
                                 root.key_locations.get("packages", root.location), "packages"))
    if errors:
        raise errors[0] if len(errors) == 1 else InputErrors(errors)
    return spec


def _gyro_params(plain: dict[str, Any], root: Node, errors: list[InputError]) -> GyroModelParams:
    values = {k: v for k, v in plain.items() if k in GYRO_SPEC}
    if "adc" in values:
        values["adc"] = AdcParams(**values["adc"])
    if "digital" in values:
        values["digital"] = DigitalParams(**values["digital"])
    params = GyroModelParams(**values)
    lo_hi = params.bias_instability_tau_range_s
    if lo_hi[0] >= lo_hi[1]:
        node = root.value["bias_instability_tau_range_s"]
        errors.append(InputError("expected [tau_min, tau_max] with tau_min < tau_max", node.location, "bias_instability_tau_range_s"))
    if params.in_run_poly_variable == "temp_channel_v" and "in_run_poly" not in plain:
        errors.append(InputError("in_run_poly_variable: temp_channel_v needs in_run_poly (Tables 3/7 coefficients)",
                                 root.value["in_run_poly_variable"].location, "in_run_poly"))
    return params


def _packages(node: Node | None, root: Node, errors: list[InputError]) -> dict[str, NasaSensorParams]:
    if node is None:
        errors.append(InputError("missing required field in sensor model (nasa_sensor)", root.location, "packages"))
        return {}
    if not isinstance(node.value, dict) or not node.value:
        errors.append(InputError(f"expected a mapping of package name to parameters, got {_describe(node.value)}", node.location, "packages"))
        return {}
    out = {}
    for name, child in node.value.items():
        n_before = len(errors)
        plain = _check_mapping(child, NASA_PACKAGE_SPEC, f"package {name!r}", f"packages.{name}.", errors,
                               required=("bias", "sensitivity", "azimuth_deg", "coning_deg"))
        if plain is _BAD or len(errors) > n_before:
            continue
        out[name] = NasaSensorParams.from_degrees(plain["bias"], plain["sensitivity"], plain["azimuth_deg"], plain["coning_deg"])
    return out


def _effects(node: Node, errors: list[InputError]) -> list[dict[str, Any]]:
    """``effects:`` list: each ``{effect: NAME, axis: x|y|z|all, params: {name: value}, source: TEXT}``."""
    if node.value is None:
        return []
    if not isinstance(node.value, list):
        errors.append(InputError(f"expected a list of effects, got {_describe(node.value)}", node.location, "effects"))
        return []
    out = []
    for i, item in enumerate(node.value):
        name = f"effects[{i}]"
        spec = {"effect": _Str(), "axis": _Choice(EFFECT_AXES), "params": _Kind(), "source": _Str(), "description": _Str()}
        n_before = len(errors)
        plain = _check_mapping(item, spec, "effect", f"{name}.", errors, required=("effect",), skip=("params",))
        if plain is _BAD:
            continue
        params: dict[str, Any] = {}
        if isinstance(item.value, dict) and "params" in item.value:
            pnode = item.value["params"]
            if not isinstance(pnode.value, dict):
                errors.append(InputError(f"expected a mapping of parameter name to value, got {_describe(pnode.value)}", pnode.location, f"{name}.params"))
            else:
                for key, val in pnode.value.items():
                    v = val.plain()
                    if not isinstance(v, EFFECT_PARAM_VALUE) or (isinstance(v, list) and not all(_is_number(x) for x in v)):
                        errors.append(InputError(f"expected a number, text, true/false or a list of numbers, got {_describe(v)}",
                                                 val.location, f"{name}.params.{key}"))
                    else:
                        params[key] = v
        if len(errors) > n_before:
            continue
        entry = {"effect": plain["effect"], "axis": plain.get("axis", "all"), "params": params}
        for extra in ("source", "description"):
            if extra in plain:
                entry[extra] = plain[extra]
        problem = _effect_problem(entry, name)
        if problem is not None:
            errors.append(InputError(problem, item.location, name))
            continue
        out.append(entry)
    return out


def _effect_problem(entry: dict[str, Any], where: str) -> str | None:
    """The effects module's complaint about ``entry`` (unknown effect or parameter, bad value), or
    None. Skipped when :mod:`bench.model.effects` is not importable."""
    try:
        from bench.model import effects as effects_mod
    except ImportError:
        return None
    try:
        effects_mod.parse_effect(entry, where)
    except InputError as exc:
        return exc.message.removeprefix(f"{where}: ")
    return None


def model_names() -> tuple[str, ...]:
    """Model names a file may give (``model:``)."""
    return MODELS


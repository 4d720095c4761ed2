"""The sensor board's config keys: its gyro compensation (``calibration:``) and its frame
description (``frames:``); in ``sim:``, the simulated sensors' model (``sensor_model:``), the
built-in-test result, and the link (UART, or CAN with its node and channel) (docs/acs-board-protocol.md,
docs/frame-descriptions.md, docs/sensor-models.md)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bench.errors import InputError, InputErrors, Location
from bench.model.imu_simple import ImuModelParams
from bench.yamlsrc import Fields, Node, load_yaml

if TYPE_CHECKING:  # pragma: no cover
    from bench.config import ConfigContext, SimConfig
    from bench.procedure.signals import StreamSignals

SENSOR_MODEL_SCHEMA = "bench-sensor-model/1"


@dataclass
class BoardSettings:
    compensation: Any = None
    """Gyro compensation (NPSAT1 Eq. 2) from the ``calibration:`` files
    (:class:`bench.model.compensation.Compensation`), or None."""
    frames: Any = None
    """The board's frame description (config ``frames:``, :class:`drivers.board_frames.FrameDescription`);
    None: our board's (docs/acs-board-protocol.md)."""

    def description(self) -> Any:
        """The frame description in force (ours when the config names none)."""
        from drivers.frame_schema import builtin_description

        return self.frames or builtin_description()

    def open_kwargs(self) -> dict[str, Any]:
        return {"compensation": self.compensation, "description": self.frames}

    def signals(self) -> "StreamSignals":
        """The signals of the board's data stream, from its frame description."""
        from bench.kinds.acs_board import ROLES
        from bench.procedure.signals import StreamSignals

        d = self.description()
        columns, vectors = d.signal_table()
        return StreamSignals(columns, vectors, d.ops, d.name, tuple((c, ROLES[c]) for c in columns if c in ROLES))

    def stream_columns(self) -> list:
        """The run-file columns of its data stream (what a replay checks a recording against)."""
        from bench.runner.ingest import board_columns

        return board_columns(self.frames)


@dataclass
class BoardSimSettings:
    bit_fail_mask: int = 0
    model: ImuModelParams = field(default_factory=ImuModelParams)
    sensor_spec: Any = None
    """The loaded model file when it is not ``imu_simple`` (:class:`bench.model.loader.SensorModelSpec`)."""
    model_path: str = ""
    can_channel: str = ""
    node_id: int = 16
    """The board's CAN node id (``transport: can``, docs/acs-board-can.md)."""


def settings(f: Fields, ctx: "ConfigContext") -> BoardSettings:
    compensation = _compensation(f.node_at("calibration"), ctx)
    frames = _frames(f.node_at("frames"), ctx)
    _check_board(frames, f, ctx.sim, compensation, ctx.errors)
    return BoardSettings(compensation, frames)


def sim_settings(f: Fields, ctx: "ConfigContext") -> BoardSimSettings:
    s = BoardSimSettings()
    s.bit_fail_mask = f.get("bit_fail_mask", int, default=0)
    s.can_channel, s.node_id = ctx.can_node(f, 16)
    model_rel = f.get("sensor_model", str)
    if model_rel is not None:
        model_path = ctx.file(f.map["sensor_model"], "sensor model", "sensor_model")
        if model_path is not None:
            s.model_path = str(model_path)
            model = _sensor_model(model_path, f.map["sensor_model"].location, ctx.errors, ctx.sources)
            ctx.keep_as_named(model_rel, model_path)
            if isinstance(model, ImuModelParams):
                s.model = model
            else:
                s.sensor_spec = model
    return s


def _compensation(node: Node | None, ctx: "ConfigContext") -> Any:
    """``calibration: FILE`` or ``[FILE, ...]`` (acs_board): gyro compensation terms, paths relative
    to the config's directory (bench/model/compensation.py); their texts into ``sources``."""
    if node is None:
        return None
    errors = ctx.errors
    items = node.value if isinstance(node.value, list) else [node]
    if not items or not all(isinstance(n.value, str) and n.value for n in items):
        errors.append(InputError("expected a calibration file or a list of them", node.location, "calibration"))
        return None
    from bench.model.compensation import load_compensation

    paths = [ctx.file(n, "calibration file", "calibration") for n in items]
    if None in paths:
        return None
    try:
        comp = load_compensation(paths, ctx.sources)
    except InputErrors as exc:
        errors.extend(exc.errors)
        return None
    except InputError as exc:
        errors.append(exc if exc.location is not None else InputError(exc.message, node.location, "calibration"))
        return None
    for n, p in zip(items, paths):
        ctx.keep_as_named(n.value, p)
    return comp


def _frames(node: Node | None, ctx: "ConfigContext") -> Any:
    """``frames: FILE`` (acs_board): the board's frame description (docs/frame-descriptions.md),
    a path relative to the config's directory or in ``configs/``; its text into ``sources``. None
    when absent (our board's frames) or bad (the errors recorded, located in that file)."""
    if node is None:
        return None
    errors = ctx.errors
    if not isinstance(node.value, str) or not node.value:
        errors.append(InputError("expected the frame description's file, e.g. frames/xsens_mti.yaml", node.location, "frames"))
        return None
    path = ctx.file(node, "frame description", "frames")
    if path is None:
        return None
    from bench.board_frames import frame_description_from_source

    try:
        src = load_yaml(path, "frame description")
        ctx.sources[str(path)] = src.text  # kept in the run file: a replay reads it from there
        description = frame_description_from_source(src)
    except InputErrors as exc:
        errors.extend(exc.errors)
        return None
    except InputError as exc:
        errors.append(InputError(f"frame description {path}: {exc.message}", exc.location if exc.location and exc.location.line else node.location, "frames"))
        return None
    ctx.keep_as_named(node.value, path)
    return description


def _check_board(frames: Any, f: Fields, sim: "SimConfig | None", compensation: Any, errors: list[InputError]) -> None:
    """What the rest of the board's settings need from its frames: a gyro and a temperature for a
    calibration, a number for the simulated serial where the board sends its serial as one."""
    from drivers.board_frames import TYPES
    from drivers.frame_schema import builtin_description

    d = frames or builtin_description()
    if compensation is not None and (d.field("gyro") is None or d.field("temp") is None):
        errors.append(InputError(f"a calibration compensates the gyro with its temperature: frame description {d.name!r} "
                                 "has no gyro or no temp field", f.map["calibration"].location, "calibration"))
    identify = d.commands["identify"].reply
    item = next((i for i in identify.payload if i.name == "serial"), None)
    if sim is not None and item is not None:
        digits = sim.serial
        ok = all(c in "0123456789abcdefABCDEF" for c in digits) if item.format == "hex" else digits.isdigit()
        width = 2 * TYPES[item.type][1]
        if not digits or not ok or (item.format == "hex" and len(digits) > width) or (ok and item.format == "dec" and int(digits) >= 1 << (4 * width)):
            where = f.map["sim"].value.get("serial") if isinstance(f.map["sim"].value, dict) else None
            errors.append(InputError(f"frame description {d.name!r} sends the serial as a {item.type} number: expected "
                                     f"{'up to ' + str(width) + ' hex digits, e.g. 037003F8' if item.format == 'hex' else 'decimal digits'}"
                                     f", got {sim.serial!r}", (where or f.map["sim"]).location, "serial"))


def _other_sensor_model(path: Path, text: str, ref: Location, errors: list[InputError]) -> Any:
    """A model file other than ``imu_simple`` (bench/model/loader.py validates ``text``, read from
    ``path``); None if bad."""
    from bench.model.loader import parse_sensor_model

    try:
        spec = parse_sensor_model(text, str(path))
    except InputErrors as exc:
        errors.extend(exc.errors)
        return None
    except InputError as exc:
        errors.append(exc)
        return None
    if spec.gyro is None and spec.imu is None:
        errors.append(InputError(f"model {spec.model!r} cannot drive the ACS board (expected imu_simple or npsat1_gyro)", ref, "sensor_model"))
        return None
    return spec


def _sensor_model(path: Path, ref: Location, errors: list[InputError], sources: dict[str, str]) -> Any:
    """The sensor model file at ``path`` (read once; its text into ``sources``)."""
    try:
        src = load_yaml(path, "sensor model")
    except InputError as exc:
        errors.append(InputError(f"sensor model {path}: {exc.message}", exc.location if exc.location and exc.location.line else ref, "sensor_model"))
        return ImuModelParams()
    sources[str(path)] = src.text  # kept in the run file: a replay reads it from there
    data: dict[str, Any] = src.root.plain()
    if isinstance(data, dict) and data.get("model") not in (None, "imu_simple"):
        return _other_sensor_model(path, src.text, ref, errors)
    if data.pop("schema", None) != SENSOR_MODEL_SCHEMA:
        errors.append(InputError(f"expected schema: {SENSOR_MODEL_SCHEMA}", src.root.location, "schema"))
    if data.pop("model", None) != "imu_simple":
        errors.append(InputError("expected model: imu_simple", src.root.location, "model"))
    try:
        params = ImuModelParams.from_dict(data)
    except KeyError as exc:
        key = str(exc.args[0]).split(",")[0]
        loc = src.root.key_locations.get(key, src.root.location)
        errors.append(InputError(f"unknown sensor-model parameter(s): {exc.args[0]}", loc, key))
        return ImuModelParams()
    for key, expected_len in (("gyro_bias_dps", 3), ("warmup_amplitude_dps", 3), ("warmup_settling_s", 3), ("accel_bias_g", 3), ("mag_bias_ut", 3)):
        value = getattr(params, key)
        if not isinstance(value, list) or len(value) != expected_len or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in value):
            errors.append(InputError(f"expected a list of {expected_len} numbers", src.root.key_locations.get(key, src.root.location), key))
    for key in ("gyro_noise_density_dps_rthz", "accel_noise_density_g_rthz", "mag_noise_rms_ut", "lowpass_cutoff_hz"):
        value = getattr(params, key)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or value < 0:
            errors.append(InputError("expected a non-negative number", src.root.key_locations.get(key, src.root.location), key))
    if not isinstance(params.gyro_bias_poly_degc, list) or not all(isinstance(x, (int, float)) for x in params.gyro_bias_poly_degc):
        errors.append(InputError("expected a list of polynomial coefficients (ascending powers)", src.root.key_locations.get("gyro_bias_poly_degc", src.root.location), "gyro_bias_poly_degc"))
    return params

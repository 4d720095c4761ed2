"""Driver of the 2-axis rate table: two CiA 402 drives (rotation at node N, tilt at N+1) on one CAN bus.

Speaks CANopen SDO through the ``canopen`` package for every command and read; monitoring uses one
SYNC and the drives' synchronous TPDOs (CiA 301: PDOs flow only in NMT OPERATIONAL and drives power
up PRE-OPERATIONAL, so :meth:`RateTable.open` sends NMT "start remote node" to both drives once
it has read their resolution and limits; a drive that still sends no PDOs, or PDOs of another
mapping, is read by SDO). Frames:
docs/golden/cia301-402.md. Objects are named once, in ``drivers/rate_table.eds``, and addressed by
their ``ParameterName`` (:class:`Obj`); the simulator (``bench.sim.rate_table``) reads the same file.
Units: degrees and deg/s at the API; counts, counts/s and counts/s^2 on the wire, converted in
:class:`AxisUnits` only, from the drive's own object 0x608F (position encoder resolution).

Errors: SDO abort -> :class:`ProtocolError` (code and meaning); no answer -> :class:`InstrumentTimeout`;
drive in FAULT -> :class:`DeviceFault` with the EMCY / 0x603F error code. Only reads are retried.
Every wait is bounded on the driver's clock (``clock=``; pass the lab's clock so a VirtualClock run
advances when the driver waits). See docs/rate-table.md.
"""

from __future__ import annotations

import collections
import math
import struct
import threading
from pathlib import Path
from typing import Callable

import can
import canopen
from canopen.emcy import EmcyError
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from drivers.base import Driver, Transient, check_timeout
from drivers.clock import WallClock
from drivers.errors import DeviceFault, InstrumentError, InstrumentTimeout, ProtocolError
from drivers.can_transport import connect_network, open_bus, parse_can_url

EDS_PATH = Path(__file__).with_name("rate_table.eds")
READ_RETRIES = 1  # reads are idempotent: one retry, both attempts within timeout_s
POLL_S = 0.05  # status polling period of waits (s, run time)
NOTIFIER_CYCLE_S = 0.05  # python-can Notifier recv timeout (wall s): bounds close() time


class Obj:
    """Object names as spelled in drivers/rate_table.eds (``ParameterName``); (record, sub) tuples."""

    DEVICE_NAME = "Manufacturer device name"
    HW_VERSION = "Manufacturer hardware version"
    SW_VERSION = "Manufacturer software version"
    VENDOR_ID = ("Identity object", "Vendor-ID")
    PRODUCT_CODE = ("Identity object", "Product code")
    REVISION = ("Identity object", "Revision number")
    SERIAL_NUMBER = ("Identity object", "Serial number")
    SERIAL_TEXT = "Serial number text"
    HEARTBEAT = "Producer heartbeat time"
    ERROR_REGISTER = "Error register"
    ERROR_CODE = "Error code"
    CONTROLWORD = "Controlword"
    STATUSWORD = "Statusword"
    MODE = "Modes of operation"
    MODE_DISPLAY = "Modes of operation display"
    POSITION_ACTUAL = "Position actual value"
    VELOCITY_ACTUAL = "Velocity actual value"
    TARGET_POSITION = "Target position"
    LIMIT_MIN = ("Software position limit", "Min position limit")
    LIMIT_MAX = ("Software position limit", "Max position limit")
    MAX_PROFILE_VELOCITY = "Max profile velocity"
    PROFILE_VELOCITY = "Profile velocity"
    PROFILE_ACCEL = "Profile acceleration"
    PROFILE_DECEL = "Profile deceleration"
    QUICK_STOP_DECEL = "Quick stop deceleration"
    MAX_ACCEL = "Max acceleration"
    TARGET_VELOCITY = "Target velocity"
    ENCODER_INCREMENTS = ("Position encoder resolution", "Encoder increments")
    ENCODER_REVOLUTIONS = ("Position encoder resolution", "Motor revolutions")


SYNC_COB_ID = 0x080
"""CiA 301 SYNC (no data): every drive answers with its transmit PDOs."""
NMT_COB_ID = 0x000
"""CiA 301 NMT node control: data [command specifier, node id]."""
NMT_START_REMOTE_NODE = 0x01
"""CiA 301 NMT command: go to OPERATIONAL (PDOs are exchanged only there)."""
TPDO_MAP: dict[int, tuple[int, tuple]] = {
    1: (0x180, (Obj.STATUSWORD, Obj.POSITION_ACTUAL)),
    2: (0x280, (Obj.VELOCITY_ACTUAL,)),
}
"""Synchronous transmit PDOs of each drive (PDO number -> (COB-ID base + node id, mapped objects in
order)): statusword u16 + position i32, then velocity i32, little-endian as in CiA 301. One SYNC
reads both axes in four frames instead of six SDO round trips (docs/rate-table.md)."""


def od_var(od: canopen.ObjectDictionary, key: str | tuple[str, str]):
    """The :class:`canopen.objectdictionary.ODVariable` named ``key`` in ``od``."""
    return od[key[0]][key[1]] if isinstance(key, tuple) else od[key]


class Cw:
    """Controlword (0x6040) commands and bits (CiA 402; shared/protocols.md section 4)."""

    DISABLE_VOLTAGE = 0x0000
    QUICK_STOP = 0x0002
    SHUTDOWN = 0x0006
    SWITCH_ON = 0x0007
    DISABLE_OPERATION = 0x0007
    ENABLE_OPERATION = 0x000F
    NEW_SET_POINT = 0x0010  # bit 4, PP: rising edge starts a move
    CHANGE_IMMEDIATELY = 0x0020  # bit 5
    RELATIVE = 0x0040  # bit 6
    FAULT_RESET = 0x0080  # bit 7, rising edge
    HALT = 0x0100  # bit 8


class Sw:
    """Statusword (0x6041) bits (CiA 402; Danfoss VLT programming manual 7.3.1)."""

    VOLTAGE_ENABLED = 1 << 4
    QUICK_STOP = 1 << 5
    WARNING = 1 << 7
    REMOTE = 1 << 9
    TARGET_REACHED = 1 << 10
    INTERNAL_LIMIT = 1 << 11
    OP12 = 1 << 12  # PV: speed = 0; PP: set-point acknowledge
    FOLLOWING_ERROR = 1 << 13  # PP


NOT_READY = "NOT READY TO SWITCH ON"
SWITCH_ON_DISABLED = "SWITCH ON DISABLED"
READY_TO_SWITCH_ON = "READY TO SWITCH ON"
SWITCHED_ON = "SWITCHED ON"
OPERATION_ENABLED = "OPERATION ENABLED"
QUICK_STOP_ACTIVE = "QUICK STOP ACTIVE"
FAULT_REACTION_ACTIVE = "FAULT REACTION ACTIVE"
FAULT = "FAULT"
# state -> (mask, value) of the statusword, as canopen profiles/p402.py State402.SW_MASK
STATES: dict[str, tuple[int, int]] = {
    NOT_READY: (0x4F, 0x00),
    SWITCH_ON_DISABLED: (0x4F, 0x40),
    READY_TO_SWITCH_ON: (0x6F, 0x21),
    SWITCHED_ON: (0x6F, 0x23),
    OPERATION_ENABLED: (0x6F, 0x27),
    QUICK_STOP_ACTIVE: (0x6F, 0x07),
    FAULT_REACTION_ACTIVE: (0x4F, 0x0F),
    FAULT: (0x4F, 0x08),
}
FAULT_STATES = (FAULT, FAULT_REACTION_ACTIVE)
MODE_PROFILE_POSITION = 1
MODE_PROFILE_VELOCITY = 3
MODE_NAMES = {MODE_PROFILE_POSITION: "PP", MODE_PROFILE_VELOCITY: "PV"}


def decode_state(statusword: int) -> str:
    """CiA 402 state name of a statusword (``"UNKNOWN"`` if it matches none)."""
    for name, (mask, value) in STATES.items():
        if statusword & mask == value:
            return name
    return "UNKNOWN"


def emcy_description(code: int) -> str:
    """Meaning of a CiA 301/402 EMCY error code, as canopen's table gives it."""
    return EmcyError(code, 0, b"", 0.0).get_desc() or "unknown"


class AxisUnits:
    """Degrees <-> drive units of one axis: ``counts_per_rev`` encoder counts per axis revolution."""

    def __init__(self, counts_per_rev: int) -> None:
        if counts_per_rev <= 0:
            raise ValueError(f"encoder resolution must be > 0 counts/rev, got {counts_per_rev}")
        self.counts_per_deg = counts_per_rev / 360.0

    def counts(self, deg: float) -> int:
        """deg -> counts (also deg/s -> counts/s, deg/s^2 -> counts/s^2), rounded."""
        return round(deg * self.counts_per_deg)

    def deg(self, counts: int) -> float:
        return counts / self.counts_per_deg


class _ErrorFrameCounter(can.Listener):
    def __init__(self) -> None:
        self.count = 0

    def on_message_received(self, msg: can.Message) -> None:
        if msg.is_error_frame:
            self.count += 1


class _Axis:
    def __init__(self, name: str, node: canopen.RemoteNode) -> None:
        self.name = name
        self.node = node
        self.units = AxisUnits(1)
        self.limits_deg = (-math.inf, math.inf)


class RateTable(Driver):
    """The 2-axis rate table: ``rotation`` (node N) and ``tilt`` (node N+1). Angles deg, rates deg/s.

    SDO reads are retried once when no answer comes (both attempts within ``timeout_s``); writes
    are sent once."""

    kind = "rate_table"
    streams = False  # no data stream: the runner records its commands and answers only

    def __init__(self, bus: can.BusABC, node_id: int = 1, *, timeout_s: float = 0.5, on_traffic=None, clock=None) -> None:
        self.bus = bus
        self.timeout_s = check_timeout(timeout_s)
        self.name = f"rate_table (nodes {node_id}, {node_id + 1})"
        self.on_traffic = on_traffic
        self.clock = clock or WallClock()
        self._lock = threading.RLock()
        self._op = ""
        self._pending: collections.deque = collections.deque(maxlen=256)
        self._errors = _ErrorFrameCounter()
        self.network = canopen.Network(bus)
        self.network.NOTIFIER_CYCLE = NOTIFIER_CYCLE_S
        self.network.listeners.append(self._errors)
        self.axes: dict[str, _Axis] = {}
        self._pdo_ok = True
        self._pdo_got: dict[int, bytes] | None = None
        self._pdo_done = threading.Event()
        for name, nid in (("rotation", node_id), ("tilt", node_id + 1)):
            node = self.network.add_node(nid, str(EDS_PATH))
            node.sdo.MAX_RETRIES = 1  # canopen: 1 = a single attempt; this driver retries reads itself
            self._hook_traffic(node)
            self.axes[name] = _Axis(name, node)
        self._layout_tpdos()
        connect_network(self.network)  # a notifier thread, or none on a synchronous in-process bus
        try:
            for ax in self.axes.values():
                ax.units = AxisUnits(self._read(ax, Obj.ENCODER_INCREMENTS) // max(self._read(ax, Obj.ENCODER_REVOLUTIONS), 1))
            tilt = self.axes["tilt"]
            lo, hi = self._read(tilt, Obj.LIMIT_MIN), self._read(tilt, Obj.LIMIT_MAX)
            tilt.limits_deg = (tilt.units.deg(lo), tilt.units.deg(hi))
            for ax in self.axes.values():
                self._start_node(ax)
        except Exception:
            self.close()
            raise

    @classmethod
    def open(cls, url: str, *, baudrate: int = 0, timeout_s: float = 0.5, on_traffic=None, **kwargs) -> "RateTable":
        """Open ``can://INTERFACE/CHANNEL?node=N`` (see drivers/can_transport.py). ``baudrate`` is
        unused (the CAN bit rate is a URL option); ``clock=`` sets the clock waits run on."""
        u = parse_can_url(url)
        bus = open_bus(u)
        try:
            return cls(bus, u.node, timeout_s=timeout_s, on_traffic=on_traffic, **kwargs)
        except Exception:
            bus.shutdown()
            raise

    def close(self) -> None:
        """Stop the notifier and release the bus (safe to call twice)."""
        if self.network.bus is not None:
            self.network.disconnect()

    def __enter__(self) -> "RateTable":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ---- identity ---------------------------------------------------------------------------
    def identify(self) -> dict[str, str]:
        """Vendor, model, serial and firmware of the rotation drive (0x1008/0x1009/0x100A/0x1018)."""
        ax = self.axes["rotation"]
        vendor = self._read(ax, Obj.VENDOR_ID)
        try:
            serial = str(self._read(ax, Obj.SERIAL_TEXT))
        except ProtocolError:  # not every drive has the manufacturer-specific text: use 0x1018 sub 4
            serial = str(self._read(ax, Obj.SERIAL_NUMBER))
        return {
            "vendor": f"0x{vendor:08X}",
            "model": str(self._read(ax, Obj.DEVICE_NAME)),
            "serial": serial,
            "firmware": str(self._read(ax, Obj.SW_VERSION)),
            "hardware": str(self._read(ax, Obj.HW_VERSION)),
            "product_code": f"0x{self._read(ax, Obj.PRODUCT_CODE):08X}",
            "revision": f"0x{self._read(ax, Obj.REVISION):08X}",
        }

    # ---- motion -----------------------------------------------------------------------------
    def set_rate(self, rate_dps: float, accel_dps2: float | None = None) -> float:
        """Turn the rotation axis at ``rate_dps`` (deg/s, signed) in profile velocity mode, ramping at
        ``accel_dps2`` (deg/s^2; None keeps the drive's profile acceleration). Returns the rate the
        drive was given after quantisation to counts/s (deg/s)."""
        ax = self.axes["rotation"]
        with self._lock:
            self._write(ax, Obj.MODE, MODE_PROFILE_VELOCITY)
            self._write_accel(ax, accel_dps2)
            counts = ax.units.counts(rate_dps)
            self._write(ax, Obj.TARGET_VELOCITY, counts)
            self._enable(ax)
            self._write(ax, Obj.CONTROLWORD, Cw.ENABLE_OPERATION)  # clears a halt
            return ax.units.deg(counts)

    def move_to(self, angle_deg: float, rate_dps: float | None = None, accel_dps2: float | None = None) -> None:
        """Move the rotation axis to ``angle_deg`` (deg, absolute, unwrapped) in profile position mode."""
        self._move(self.axes["rotation"], angle_deg, rate_dps, accel_dps2)

    def tilt(self, angle_deg: float, rate_dps: float | None = None, accel_dps2: float | None = None) -> None:
        """Move the tilt axis to ``angle_deg`` (deg); ValueError outside the drive's software limits."""
        ax = self.axes["tilt"]
        lo, hi = ax.limits_deg
        if not lo <= angle_deg <= hi:
            raise ValueError(f"tilt {angle_deg:g} deg outside the drive's limits {lo:g}..{hi:g} deg")
        self._move(ax, angle_deg, rate_dps, accel_dps2)

    def stop(self) -> None:
        """Halt both axes (controlword bit 8): decelerate at the profile deceleration, stay enabled."""
        with self._lock:
            for ax in self.axes.values():
                state = decode_state(self._read(ax, Obj.STATUSWORD))
                if state == OPERATION_ENABLED:
                    self._write(ax, Obj.CONTROLWORD, Cw.ENABLE_OPERATION | Cw.HALT)

    def safe_state(self) -> str:
        """Both axes to rest and de-energised: quick stop (0x6085 deceleration), wait for zero speed
        (bounded), then disable voltage. A faulted axis is already without torque and is left as is;
        the other axis is still stopped. Raises the first error met, after trying both axes.
        Returns what each axis was told."""
        first: Exception | None = None
        done = []
        for ax in self.axes.values():
            try:
                done.append(f"{ax.name}: {self._safe_axis(ax)}")
            except InstrumentError as exc:
                first = first or exc
        if first is not None:
            raise first
        return "; ".join(done)

    # ---- status -----------------------------------------------------------------------------
    def monitor_columns(self) -> list[str]:
        """Columns of :meth:`monitor` (units deg, deg/s, deg and two dimensionless status words, declared by the kind)."""
        return ["angle", "rate", "tilt", "statusword", "tilt_statusword"]

    def monitor(self) -> dict[str, float]:
        """Angle (deg), rate (deg/s), tilt (deg) and both status words, logged every poll interval:
        one SYNC and the drives' synchronous PDOs; drives that do not answer PDOs are read by SDO."""
        pdo = self.sync_read() if self._pdo_ok else None
        if pdo is None:
            self._pdo_ok = False
            r = self.read()
            return {"angle": r["angle_deg"], "rate": r["rate_dps"], "tilt": r["tilt_deg"],
                    "statusword": float(r["statusword"]), "tilt_statusword": float(r["tilt_statusword"])}
        rot, tilt = pdo["rotation"], pdo["tilt"]
        return {"angle": rot["angle_deg"], "rate": rot["rate_dps"], "tilt": tilt["angle_deg"],
                "statusword": float(rot["statusword"]), "tilt_statusword": float(tilt["statusword"])}

    def sync_read(self) -> dict[str, dict[str, float]] | None:
        """Send SYNC and decode every axis' transmit PDOs (:data:`TPDO_MAP`): per axis statusword,
        angle_deg, rate_dps. None when a PDO does not come within the timeout (``timeout_s``, wall s)
        or has another length than :data:`TPDO_MAP` gives."""
        with self._lock:
            want = self._tpdo_cobs
            got: dict[int, bytes] = {}
            self._pdo_done.clear()
            self._pdo_got = got  # filled by _on_pdo (the notifier thread, or this one on a synchronous bus)
            try:
                self._emit("command", "SYNC", SYNC_COB_ID, b"")
                self.network.send_message(SYNC_COB_ID, b"")
                if len(got) < len(want):
                    self._pdo_done.wait(self.timeout_s)
            except can.CanError as exc:
                raise InstrumentError(f"rate_table: SYNC failed: {exc}") from None
            finally:
                self._pdo_got = None
            if len(got) < len(want):
                return None
            out: dict[str, dict[str, float]] = {}
            for ax, pdos in self._tpdo_layout:
                values = {}
                for cob, name, fields, length in pdos:
                    data = got[cob]
                    self._emit("reply", name, cob, data)
                    if len(data) != length:
                        return None  # a drive with another mapping: the caller falls back to SDO
                    off = 0
                    for key, var, size in fields:
                        values[key] = var.decode_raw(data[off:off + size])
                        off += size
                out[ax.name] = {"statusword": values[Obj.STATUSWORD], "angle_deg": ax.units.deg(values[Obj.POSITION_ACTUAL]),
                                "rate_dps": ax.units.deg(values[Obj.VELOCITY_ACTUAL])}
            return out

    def _on_pdo(self, can_id: int, data: bytearray, timestamp: float) -> None:
        got = self._pdo_got
        if got is None:
            return  # not waiting for PDOs: nobody asked for these
        got[can_id] = bytes(data)
        if len(got) >= len(self._tpdo_cobs):
            self._pdo_done.set()

    def _layout_tpdos(self) -> None:
        """Per axis, its transmit PDOs (:data:`TPDO_MAP`): (COB-ID, traffic name, (object, OD variable,
        bytes) of each mapped object, length in bytes); the PDO handler subscribed once for all."""
        self._tpdo_layout = []
        for ax in self.axes.values():
            pdos = []
            for base, keys in TPDO_MAP.values():
                fields = [(key, var, len(var.encode_raw(0))) for key in keys for var in [od_var(ax.node.object_dictionary, key)]]
                pdos.append((ax.node.id + base, f"TPDO 0x{ax.node.id + base:03X}", fields, sum(f[2] for f in fields)))
            self._tpdo_layout.append((ax, pdos))
        self._tpdo_cobs = [cob for _, pdos in self._tpdo_layout for cob, *_ in pdos]
        for cob in self._tpdo_cobs:
            self.network.subscribe(cob, self._on_pdo)

    def read(self) -> dict:
        """Angles (deg), rates (deg/s), CiA 402 states and decoded statusword bits of both axes.

        Does not raise on a drive fault (``fault`` is reported); commands and waits do.
        """
        out: dict = {}
        with self._lock:
            for ax in self.axes.values():
                pre = "" if ax.name == "rotation" else "tilt_"
                sw = self._read(ax, Obj.STATUSWORD)
                pos = self._read(ax, Obj.POSITION_ACTUAL)
                vel = self._read(ax, Obj.VELOCITY_ACTUAL)
                key = "angle_deg" if ax.name == "rotation" else "tilt_deg"
                out[key] = ax.units.deg(pos)
                out[pre + "rate_dps"] = ax.units.deg(vel)
                out[pre + "state"] = decode_state(sw)
                out[pre + "statusword"] = sw
                out[pre + "target_reached"] = bool(sw & Sw.TARGET_REACHED)
                out[pre + "warning"] = bool(sw & Sw.WARNING)
                out[pre + "internal_limit"] = bool(sw & Sw.INTERNAL_LIMIT)
                out[pre + "following_error"] = bool(sw & Sw.FOLLOWING_ERROR)
                out[pre + "fault"] = decode_state(sw) in FAULT_STATES
        out["any_fault"] = out["fault"] or out["tilt_fault"]
        out["error_frames"] = self._errors.count
        return out

    def wait_until(self, predicate: Callable[[dict], bool] | None = None, timeout_s: float = 10.0) -> dict:
        """Poll :meth:`read` every 0.05 s of run time until ``predicate(reading)`` (default: both axes
        report target reached). Returns the reading; :class:`InstrumentTimeout` after ``timeout_s``
        (run s), :class:`DeviceFault` as soon as a drive faults."""
        pred = predicate or (lambda r: r["target_reached"] and r["tilt_target_reached"])
        deadline = self.clock.now() + timeout_s
        while True:
            r = self.read()
            for ax in self.axes.values():
                pre = "" if ax.name == "rotation" else "tilt_"
                if r[pre + "fault"]:
                    raise self._fault(ax)
            if pred(r):
                return r
            if self.clock.now() >= deadline:
                raise InstrumentTimeout(f"rate_table: condition not met within {timeout_s:g} s (last reading {r})")
            self.clock.sleep(min(POLL_S, max(deadline - self.clock.now(), 0.0)) or POLL_S)

    def reset_fault(self, axis: str = "rotation") -> None:
        """Fault reset (controlword bit 7 rising edge) of ``axis``; the drive returns to SWITCH ON DISABLED."""
        ax = self.axes[axis]
        self._write(ax, Obj.CONTROLWORD, Cw.DISABLE_VOLTAGE)
        self._write(ax, Obj.CONTROLWORD, Cw.FAULT_RESET)
        self._await_state(ax, (SWITCH_ON_DISABLED,))

    def _start_node(self, ax: _Axis) -> None:
        """NMT "start remote node" (CiA 301 [0x01, node]): synchronous TPDOs flow only in OPERATIONAL."""
        self._emit("command", f"NMT start node {ax.node.id}", NMT_COB_ID, bytes([NMT_START_REMOTE_NODE, ax.node.id]))
        try:
            ax.node.nmt.send_command(NMT_START_REMOTE_NODE)
        except can.CanError as exc:
            raise InstrumentError(f"rate_table {ax.name} (node {ax.node.id}): NMT start failed: {exc}") from None

    # ---- internals: state machine -----------------------------------------------------------
    def _move(self, ax: _Axis, angle_deg: float, rate_dps: float | None, accel_dps2: float | None) -> None:
        counts = ax.units.counts(angle_deg)
        if not -(2 ** 31) <= counts < 2 ** 31:
            raise ValueError(f"{ax.name}: {angle_deg:g} deg is outside the drive's 32-bit position range")
        with self._lock:
            self._write(ax, Obj.MODE, MODE_PROFILE_POSITION)
            if rate_dps is not None:
                self._write(ax, Obj.PROFILE_VELOCITY, ax.units.counts(abs(rate_dps)))
            self._write_accel(ax, accel_dps2)
            self._write(ax, Obj.TARGET_POSITION, counts)
            self._enable(ax)
            self._write(ax, Obj.CONTROLWORD, Cw.ENABLE_OPERATION)
            self._write(ax, Obj.CONTROLWORD, Cw.ENABLE_OPERATION | Cw.NEW_SET_POINT | Cw.CHANGE_IMMEDIATELY)
            self._await_bits(ax, Sw.OP12, "set-point acknowledge")
            self._write(ax, Obj.CONTROLWORD, Cw.ENABLE_OPERATION)

    def _write_accel(self, ax: _Axis, accel_dps2: float | None) -> None:
        if accel_dps2 is None:
            return
        if not accel_dps2 > 0:
            raise ValueError(f"acceleration must be > 0 deg/s^2, got {accel_dps2!r}")
        counts = ax.units.counts(accel_dps2)
        self._write(ax, Obj.PROFILE_ACCEL, counts)
        self._write(ax, Obj.PROFILE_DECEL, counts)

    def _enable(self, ax: _Axis) -> None:
        state = decode_state(self._read(ax, Obj.STATUSWORD))
        if state in FAULT_STATES:
            raise self._fault(ax)
        if state == OPERATION_ENABLED:
            return
        if state == QUICK_STOP_ACTIVE:
            self._write(ax, Obj.CONTROLWORD, Cw.DISABLE_VOLTAGE)
            state = self._await_state(ax, (SWITCH_ON_DISABLED,))
        steps = {
            NOT_READY: [(Cw.SHUTDOWN, READY_TO_SWITCH_ON)],
            SWITCH_ON_DISABLED: [(Cw.SHUTDOWN, READY_TO_SWITCH_ON)],
            READY_TO_SWITCH_ON: [],
            SWITCHED_ON: [],
        }
        if state not in steps:
            raise ProtocolError(f"rate_table {ax.name}: drive in unexpected state {state!r}")
        plan = steps[state]
        if state != SWITCHED_ON:
            plan = plan + [(Cw.SWITCH_ON, SWITCHED_ON)]
        plan = plan + [(Cw.ENABLE_OPERATION, OPERATION_ENABLED)]
        for cw, want in plan:
            self._write(ax, Obj.CONTROLWORD, cw)
            self._await_state(ax, (want,))

    def _await_state(self, ax: _Axis, wanted: tuple[str, ...]) -> str:
        deadline = self.clock.now() + self.timeout_s
        while True:
            state = decode_state(self._read(ax, Obj.STATUSWORD))
            if state in wanted:
                return state
            if state in FAULT_STATES:
                raise self._fault(ax)
            if self.clock.now() >= deadline:
                raise InstrumentTimeout(f"rate_table {ax.name}: drive stayed in {state!r}, expected {' or '.join(wanted)}")
            self.clock.sleep(POLL_S / 5)

    def _await_bits(self, ax: _Axis, bits: int, what: str) -> None:
        deadline = self.clock.now() + self.timeout_s
        while True:
            sw = self._read(ax, Obj.STATUSWORD)
            if sw & bits == bits:
                return
            if decode_state(sw) in FAULT_STATES:
                raise self._fault(ax)
            if self.clock.now() >= deadline:
                raise InstrumentTimeout(f"rate_table {ax.name}: no {what} (statusword 0x{sw:04X})")
            self.clock.sleep(POLL_S / 5)

    def _safe_axis(self, ax: _Axis) -> str:
        """Bring one axis to rest and disable its voltage; returns what it was told."""
        state = decode_state(self._read(ax, Obj.STATUSWORD))
        if state in FAULT_STATES:
            return "in FAULT, left without torque"
        told = "disable voltage (0x6040 = 0x00)"
        if state == OPERATION_ENABLED:
            told = "quick stop (0x6040 = 0x02), stopped, " + told
            self._write(ax, Obj.CONTROLWORD, Cw.QUICK_STOP)
            rate = abs(self._read(ax, Obj.VELOCITY_ACTUAL))
            decel = max(self._read(ax, Obj.QUICK_STOP_DECEL), 1)
            deadline = self.clock.now() + rate / decel + self.timeout_s
            while rate != 0:
                if self.clock.now() >= deadline:
                    raise InstrumentTimeout(f"rate_table {ax.name}: still turning after quick stop ({ax.units.deg(rate):g} deg/s)")
                self.clock.sleep(min(POLL_S, max(deadline - self.clock.now(), 0.0)) or POLL_S)
                rate = abs(self._read(ax, Obj.VELOCITY_ACTUAL))
        self._write(ax, Obj.CONTROLWORD, Cw.DISABLE_VOLTAGE)
        return told

    def _fault(self, ax: _Axis) -> DeviceFault:
        code = None
        log = ax.node.emcy.active or ax.node.emcy.log
        if log:
            code = log[-1].code
        try:
            code = self._read(ax, Obj.ERROR_CODE) or code
        except InstrumentError:
            pass
        text = "no error code" if code is None else f"error code 0x{code:04X} ({emcy_description(code)})"
        exc = DeviceFault(f"rate_table {ax.name} (node {ax.node.id}): drive in FAULT, {text}")
        exc.error_code = code
        return exc

    # ---- internals: SDO with typed errors and traffic ----------------------------------------
    def _read(self, ax: _Axis, key):
        return self._sdo(ax, key, None)

    def _write(self, ax: _Axis, key, value) -> None:
        self._sdo(ax, key, value)

    def _sdo(self, ax: _Axis, key, value):
        var = od_var(ax.node.object_dictionary, key)
        reading = value is None
        sub = f"sub{var.subindex}" if var.subindex else ""
        label = (var.name if not isinstance(key, tuple) else f"{key[0]} {key[1]}").lower().replace(" ", "_").replace("-", "_")
        self._op = f"SDO {'read' if reading else 'write'} 0x{var.index:04X}{sub} {label}"
        where = f"rate_table {ax.name} (node {ax.node.id}): {self._op}"
        attempts = 1 + READ_RETRIES if reading else 1
        sdo = ax.node.sdo
        sdo.RESPONSE_TIMEOUT = self.timeout_s / attempts  # both attempts of a read within timeout_s

        def attempt(_: int):
            try:
                if reading:
                    return var.decode_raw(sdo.upload(var.index, var.subindex))
                sdo.download(var.index, var.subindex, var.encode_raw(value))
                return None
            except SdoAbortedError as exc:
                raise ProtocolError(f"{where}: SDO abort 0x{exc.code:08X} ({_abort_text(exc)})") from None
            except SdoCommunicationError as exc:
                if "No SDO response" not in str(exc):
                    raise ProtocolError(f"{where}: {exc}") from None
                raise Transient(InstrumentTimeout(f"{where}: no answer within {self.timeout_s:g} s")) from None
            except can.CanError as exc:
                raise InstrumentError(f"{where}: CAN error: {exc}") from None
            except (struct.error, ValueError, TypeError) as exc:
                raise ProtocolError(f"{where}: bad data: {exc}") from None

        try:
            return self.read_retrying(attempt, attempts=attempts)
        finally:
            self._flush_traffic()

    def _hook_traffic(self, node: canopen.RemoteNode) -> None:
        send = node.sdo.send_request
        cob = node.sdo.rx_cobid

        def send_request(request) -> None:
            self._flush_traffic()
            self._emit("command", self._op, cob, bytes(request))
            send(request)

        node.sdo.send_request = send_request
        self.network.subscribe(node.sdo.tx_cobid, self._on_frame)
        self.network.subscribe(0x80 + node.id, self._on_frame)  # EMCY COB-ID (CiA 301)

    def _on_frame(self, can_id: int, data: bytearray, timestamp: float) -> None:
        self._pending.append((can_id, bytes(data)))

    def _flush_traffic(self) -> None:
        while self._pending:
            can_id, data = self._pending.popleft()
            name = self._op
            if can_id & 0x780 == 0x080 and len(data) >= 2:
                code = int.from_bytes(data[:2], "little")
                name = f"EMCY 0x{code:04X} {emcy_description(code)}"
            self._emit("reply", name, can_id, data)

    def _emit(self, direction: str, name: str, can_id: int, data: bytes) -> None:
        if self.on_traffic is not None:
            self.on_traffic(direction, name, can_id.to_bytes(2, "big") + data)


def _abort_text(exc: SdoAbortedError) -> str:
    return SdoAbortedError.CODES.get(exc.code, "unknown abort code")

"""Simulated 2-axis rate table: two CiA 402 drives as canopen ``LocalNode``s on a python-can bus.

Each drive is a ``LocalNode`` built from ``drivers/rate_table.eds`` (rotation at node N, tilt at
N+1) whose read/write callbacks run the CiA 402 state machine (controlword -> state, statusword),
profile position (mode 1) and profile velocity (mode 3), and compute actual position/velocity
from the axis kinematics (:class:`bench.sim.table_motion.AxisMotion`) at ``clock.now()``.

Time: SDOs are answered at once in wall time (on the network's notifier thread on a python-can
bus; in the sender's thread on a :class:`drivers.can_transport.SyncBus`, the dry-run default); state
is evaluated at ``clock.now()``, so with a VirtualClock the table only moves when the host sleeps.
No heartbeat is produced unless the host writes 0x1017 (canopen then runs it in wall time; its
content does not depend on run time).

NMT (CiA 301): each drive sends its boot-up message (0x700 + id, ``00``) when attached and is then
PRE-OPERATIONAL (heartbeat ``7F``); NMT start/stop/enter pre-operational are obeyed, reset node and
reset communication repeat the boot-up (the drive's CiA 402 state is kept: a simplification).
Synchronous TPDOs are sent only in OPERATIONAL; in STOPPED the drives answer neither SDOs nor send
EMCY (docs/golden/cia301-402.md).

Fault hooks (``inject(fault, **params)``, ``clear_faults()``; docs/rate-table.md):

* ``sdo_abort``: ``code`` (default 0x08000020, "data cannot be transferred"), ``index`` (only that
  object; default all), ``count`` (aborts before it heals; default until cleared), ``axis``;
* ``silent``: the drives stop answering (as a bus-off node seen from the host), ``axis`` or both;
* ``error_frames``: ``count`` CAN error frames sent on the bus at once (python-can's virtual bus
  carries them; SLCAN cannot, the gateway reports them in its ``F`` status flags);
* ``stuck``: ``axis`` stops at once (max deceleration) and no longer follows commands;
* ``fault``: ``axis`` goes to FAULT with an EMCY ``code`` (default 0x2310, continuous over-current),
  decelerating at the quick-stop deceleration; a fault reset (controlword bit 7) clears it;
* ``warning``: statusword bit 7 set on ``axis``.
"""

from __future__ import annotations

import re
import threading

import can
import canopen
from canopen.sdo.exceptions import SdoAbortedError

from bench.sim.table_motion import AxisMotion
from drivers.can_transport import connect_network
from drivers.rate_table import (
    EDS_PATH,
    FAULT,
    MODE_PROFILE_POSITION,
    MODE_PROFILE_VELOCITY,
    NOTIFIER_CYCLE_S,
    OPERATION_ENABLED,
    QUICK_STOP_ACTIVE,
    READY_TO_SWITCH_ON,
    STATES,
    SYNC_COB_ID,
    SWITCH_ON_DISABLED,
    SWITCHED_ON,
    TPDO_MAP,
    NMT_COB_ID,
    Cw,
    Obj,
    Sw,
    od_var,
)

ABORT_RANGE = 0x06090030  # CiA 301: value range of parameter exceeded
ABORT_TOO_HIGH = 0x06090031
ABORT_TOO_LOW = 0x06090032
ABORT_STATE = 0x08000022  # CiA 301: not possible in the present device state
ABORT_DEFAULT_INJECTED = 0x08000020  # CiA 301: data cannot be transferred or stored
EMCY_OVER_CURRENT = 0x2310  # CiA 402 error code: continuous over current
ERROR_REGISTER_GENERIC = 0x01  # CiA 301 0x1001 bit 0
ERROR_REGISTER_CURRENT = 0x02  # CiA 301 0x1001 bit 1
DEFAULT_TILT_LIMITS_DEG = (-120.0, 120.0)  # [U] assumed TRT-7 tilt range; NPSAT1 used -36.4 and 52.6 deg
AXES = ("rotation", "tilt")
NMT_ENTER_PRE_OPERATIONAL = 0x80  # CiA 301 NMT command specifiers
NMT_RESET_NODE = 0x81
NMT_RESET_COMMUNICATION = 0x82


class AxisDrive:
    """One CiA 402 drive: a ``LocalNode`` plus the state machine over an :class:`AxisMotion`."""

    def __init__(self, clock, motion: AxisMotion, node_id: int, axis: str, serial: str,
                 limits_deg: tuple[float, float] | None = None) -> None:
        self.clock = clock
        self.motion = motion
        self.axis = axis
        self.node = canopen.LocalNode(node_id, canopen.import_od(str(EDS_PATH), node_id))
        self.od = self.node.object_dictionary
        self._lock = threading.RLock()
        self.cpd = self._default(Obj.ENCODER_INCREMENTS) / (self._default(Obj.ENCODER_REVOLUTIONS) * 360.0)
        motion.counts_per_rev = round(self.cpd * 360)
        self.state = SWITCH_ON_DISABLED
        self.cw = 0
        self.halted = False
        self.set_point_ack = False
        self.move_pending = False
        self.limit_hit = False
        self.stuck = False
        self.warning = False
        self.fault_code = 0
        self.error_register = 0
        self.aborts: dict | None = None
        # identity and limits as this axis' drive reports them
        self._store(Obj.DEVICE_NAME, f"TRT-7 {axis} axis drive (simulated)")
        self._store(Obj.SERIAL_TEXT, serial)
        digits = re.sub(r"\D", "", serial)
        self._store(Obj.SERIAL_NUMBER, int(digits[-9:]) if digits else 0)
        self._store(Obj.MAX_PROFILE_VELOCITY, self._c(motion.max_rate_dps))
        self._store(Obj.MAX_ACCEL, self._c(motion.max_accel_dps2))
        if limits_deg is not None:
            self._store(Obj.LIMIT_MIN, self._c(limits_deg[0]))
            self._store(Obj.LIMIT_MAX, self._c(limits_deg[1]))
        self._writers = {
            self._index(Obj.CONTROLWORD): self._on_controlword,
            self._index(Obj.MODE): self._on_mode,
            self._index(Obj.TARGET_VELOCITY): self._on_target_velocity,
            self._index(Obj.PROFILE_VELOCITY): self._on_profile_velocity,
            self._index(Obj.PROFILE_ACCEL): self._on_accel,
            self._index(Obj.PROFILE_DECEL): self._on_accel,
            self._index(Obj.QUICK_STOP_DECEL): self._on_accel,
        }
        self._readers_by_key: dict = {}
        self._readers = {
            self._index(Obj.STATUSWORD): self.statusword,
            self._index(Obj.POSITION_ACTUAL): self._position_counts,
            self._index(Obj.VELOCITY_ACTUAL): lambda: self.motion.velocity_counts(self.clock.now()),
            self._index(Obj.MODE_DISPLAY): lambda: self.mode,
            self._index(Obj.ERROR_CODE): lambda: self.fault_code,
            self._index(Obj.ERROR_REGISTER): lambda: self.error_register,
        }
        self.tpdos = [(base, [(key, od_var(self.od, key)) for key in keys]) for base, keys in TPDO_MAP.values()]
        """Transmit PDOs (:data:`TPDO_MAP`): (COB-ID base, (object, OD variable) of each mapped object)."""
        self.node.add_read_callback(self._on_read)
        self.node.add_write_callback(self._on_write)

    # ---- object access ----------------------------------------------------------------------
    def pdo_value(self, key):
        """Value of a PDO-mapped object now (the same reader an SDO upload uses)."""
        with self._lock:
            reader = self._readers_by_key.get(key)
            if reader is None:
                reader = self._readers_by_key[key] = self._readers.get(self._index(key)) or (lambda: self.value(key))
            return reader()

    def _index(self, key) -> int:
        return od_var(self.od, key).index

    def _default(self, key):
        return od_var(self.od, key).default

    def value(self, key):
        """Current value of object ``key`` (stored, else EDS default)."""
        var = od_var(self.od, key)
        try:
            return var.decode_raw(self.node.data_store[var.index][var.subindex])
        except KeyError:
            return var.default

    def _store(self, key, value) -> None:
        var = od_var(self.od, key)
        self.node.data_store.setdefault(var.index, {})[var.subindex] = var.encode_raw(value)

    def _c(self, deg: float) -> int:
        return round(deg * self.cpd)

    def _deg(self, counts: int) -> float:
        return counts / self.cpd

    @property
    def mode(self) -> int:
        return int(self.value(Obj.MODE))

    # ---- callbacks (canopen LocalNode) ------------------------------------------------------
    def _check_abort(self, index: int) -> None:
        a = self.aborts
        if a is None or (a["index"] is not None and a["index"] != index):
            return
        if a["count"] is not None:
            a["count"] -= 1
            if a["count"] <= 0:
                self.aborts = None
        raise SdoAbortedError(a["code"])

    def _on_read(self, index: int, subindex: int, od):
        with self._lock:
            self._check_abort(index)
            reader = self._readers.get(index)
            return None if reader is None else reader()

    def _on_write(self, index: int, subindex: int, od, data: bytes) -> None:
        with self._lock:
            self._check_abort(index)
            handler = self._writers.get(index)
            if handler is not None:
                handler(od.decode_raw(data))

    # ---- state machine ----------------------------------------------------------------------
    def _on_controlword(self, cw: int) -> None:
        prev, self.cw = self.cw, cw
        now = self.clock.now()
        st = self.state
        if st == FAULT:
            if cw & Cw.FAULT_RESET and not prev & Cw.FAULT_RESET:
                self.state = SWITCH_ON_DISABLED
                self.fault_code = 0
                self.error_register = 0
                self.node.emcy.reset()
            return
        if not cw & 0x02:  # disable voltage
            if st in (READY_TO_SWITCH_ON, SWITCHED_ON, OPERATION_ENABLED, QUICK_STOP_ACTIVE):
                self._halt_motion(now, self.value(Obj.QUICK_STOP_DECEL))
                self.state = SWITCH_ON_DISABLED
            return
        if not cw & 0x04:  # quick stop
            if st == OPERATION_ENABLED:
                self._halt_motion(now, self.value(Obj.QUICK_STOP_DECEL))
                self.state = QUICK_STOP_ACTIVE
            elif st in (READY_TO_SWITCH_ON, SWITCHED_ON):
                self.state = SWITCH_ON_DISABLED
            return
        low = cw & 0x0F
        if low & 0x07 == 0x06:  # shutdown
            if st == OPERATION_ENABLED:
                self._halt_motion(now, self.value(Obj.QUICK_STOP_DECEL))
            if st in (SWITCH_ON_DISABLED, SWITCHED_ON, OPERATION_ENABLED):
                self.state = READY_TO_SWITCH_ON
            return
        if low == 0x07:  # switch on / disable operation
            if st == READY_TO_SWITCH_ON:
                self.state = SWITCHED_ON
            elif st == OPERATION_ENABLED:
                self._halt_motion(now, self.value(Obj.PROFILE_DECEL))
                self.state = SWITCHED_ON
            return
        if low == 0x0F:  # enable operation
            if st in (READY_TO_SWITCH_ON, SWITCHED_ON, QUICK_STOP_ACTIVE):
                self.state = OPERATION_ENABLED
                self.halted = bool(cw & Cw.HALT)
                self.move_pending = False
                if self.mode == MODE_PROFILE_VELOCITY and not self.halted:
                    self._apply_velocity(now)
            elif st == OPERATION_ENABLED:
                self._operation_bits(now, cw, prev)

    def _operation_bits(self, now: float, cw: int, prev: int) -> None:
        halt, was_halted = bool(cw & Cw.HALT), self.halted
        self.halted = halt
        if halt and not was_halted:
            self._halt_motion(now, self.value(Obj.PROFILE_DECEL))
            self.move_pending = False
        elif not halt and was_halted and self.mode == MODE_PROFILE_VELOCITY:
            self._apply_velocity(now)
        if self.mode == MODE_PROFILE_POSITION:
            if cw & Cw.NEW_SET_POINT and not prev & Cw.NEW_SET_POINT and not halt:
                self._start_move(now, relative=bool(cw & Cw.RELATIVE))
            if not cw & Cw.NEW_SET_POINT:
                self.set_point_ack = False

    def _start_move(self, now: float, relative: bool) -> None:
        target = self.value(Obj.TARGET_POSITION)
        if relative:
            target += self._position_counts()
        lo, hi = self.value(Obj.LIMIT_MIN), self.value(Obj.LIMIT_MAX)
        self.limit_hit = not lo <= target <= hi
        target = min(max(target, lo), hi)
        rate = self._deg(self.value(Obj.PROFILE_VELOCITY))
        accel = self._deg(min(self.value(Obj.PROFILE_ACCEL), self.value(Obj.PROFILE_DECEL)))
        self.set_point_ack = True
        self.move_pending = True
        if not self.stuck:
            self.motion.command_position(now, self._deg(target), rate, accel)

    def _apply_velocity(self, now: float) -> None:
        if self.stuck or self.state != OPERATION_ENABLED or self.halted:
            return
        v = self._deg(self.value(Obj.TARGET_VELOCITY))
        _, current = self.motion.commanded_state(now)
        speeding_up = abs(v) > abs(current) and v * current >= 0
        accel = self.value(Obj.PROFILE_ACCEL if speeding_up else Obj.PROFILE_DECEL)
        self.motion.command_rate(now, v, self._deg(accel))

    def _halt_motion(self, now: float, decel_counts: int) -> None:
        if self.stuck:
            return
        decel = min(self._deg(decel_counts), self.motion.max_accel_dps2)
        self.motion.stop(now, decel)

    # ---- writes of mode and profile parameters ----------------------------------------------
    def _on_mode(self, mode: int) -> None:
        if mode not in (MODE_PROFILE_POSITION, MODE_PROFILE_VELOCITY):
            raise SdoAbortedError(ABORT_RANGE)
        if mode != self.mode and self.state == OPERATION_ENABLED:
            self._halt_motion(self.clock.now(), self.value(Obj.PROFILE_DECEL))
            self.move_pending = False

    def _on_target_velocity(self, counts: int) -> None:
        if abs(counts) > self.value(Obj.MAX_PROFILE_VELOCITY):
            raise SdoAbortedError(ABORT_TOO_HIGH)
        if self.mode == MODE_PROFILE_VELOCITY and self.state == OPERATION_ENABLED:
            # stored after the callback returns: apply with the new value
            self._store(Obj.TARGET_VELOCITY, counts)
            self._apply_velocity(self.clock.now())

    def _on_profile_velocity(self, counts: int) -> None:
        if counts > self.value(Obj.MAX_PROFILE_VELOCITY):
            raise SdoAbortedError(ABORT_TOO_HIGH)
        if counts == 0:
            raise SdoAbortedError(ABORT_TOO_LOW)

    def _on_accel(self, counts: int) -> None:
        if counts > self.value(Obj.MAX_ACCEL):
            raise SdoAbortedError(ABORT_TOO_HIGH)
        if counts == 0:
            raise SdoAbortedError(ABORT_TOO_LOW)

    # ---- reported values --------------------------------------------------------------------
    def _position_counts(self) -> int:
        c = self.motion.position_counts(self.clock.now())
        return (c + 2 ** 31) % 2 ** 32 - 2 ** 31  # a 32-bit position register wraps

    def statusword(self) -> int:
        with self._lock:
            now = self.clock.now()
            sw = STATES[self.state][1] | Sw.REMOTE
            if self.state in (READY_TO_SWITCH_ON, SWITCHED_ON, OPERATION_ENABLED, QUICK_STOP_ACTIVE):
                sw |= Sw.VOLTAGE_ENABLED
            if self.warning:
                sw |= Sw.WARNING
            settled = now >= self.motion.settled_at()
            _, rate = self.motion.commanded_state(now)
            if self.state == OPERATION_ENABLED and self.mode == MODE_PROFILE_POSITION:
                if self.set_point_ack:
                    sw |= Sw.OP12
                if self.stuck and self.move_pending:
                    sw |= Sw.FOLLOWING_ERROR
                elif settled:
                    sw |= Sw.TARGET_REACHED
                    self.move_pending = False
                if self.limit_hit:
                    sw |= Sw.INTERNAL_LIMIT
            else:
                if rate == 0.0:
                    sw |= Sw.OP12
                if settled and not (self.stuck and self.state == OPERATION_ENABLED and not self.halted
                                    and self.value(Obj.TARGET_VELOCITY) != 0):
                    sw |= Sw.TARGET_REACHED
            return sw

    # ---- faults -----------------------------------------------------------------------------
    def enter_fault(self, code: int) -> None:
        with self._lock:
            self._halt_motion(self.clock.now(), self.value(Obj.QUICK_STOP_DECEL))
            self.state = FAULT
            self.fault_code = code
            self.error_register = ERROR_REGISTER_GENERIC | (ERROR_REGISTER_CURRENT if code & 0xF000 == 0x2000 else 0)
        if self.node.nmt.state != "STOPPED":  # CiA 301: a STOPPED node sends no EMCY
            self.node.emcy.send(code, self.error_register)

    def set_stuck(self, stuck: bool) -> None:
        with self._lock:
            if stuck and not self.stuck:
                self.motion.stop(self.clock.now(), self.motion.max_accel_dps2)
            self.stuck = stuck


class RateTableSim:
    """The simulated table: rotation drive at ``node_id``, tilt drive at ``node_id + 1``.

    :param clock: run-time clock (s) the drives evaluate motion at
    :param rotation_motion: kinematics of the rotation axis (default: :class:`AxisMotion` defaults)
    :param tilt_motion: kinematics of the tilt axis
    :param serial: serial number text of the rotation drive (the tilt drive gets ``serial + "-T"``)
    :param bus: a python-can bus (a :class:`~drivers.can_transport.SyncBus` too), or a virtual
        channel name, to attach to at once; a bus given is shut down by :meth:`close`
    """

    def __init__(self, clock, rotation_motion: AxisMotion | None = None, tilt_motion: AxisMotion | None = None,
                 node_id: int = 1, serial: str = "SIM-0003", *, bus: can.BusABC | str | None = None,
                 tilt_limits_deg: tuple[float, float] = DEFAULT_TILT_LIMITS_DEG) -> None:
        if not 1 <= node_id <= 126:
            raise ValueError(f"node id {node_id} must be 1..126 (the tilt drive uses node_id + 1)")
        self.clock = clock
        self.node_id = node_id
        self.drives = {
            "rotation": AxisDrive(clock, rotation_motion or AxisMotion(), node_id, "rotation", serial),
            "tilt": AxisDrive(clock, tilt_motion or AxisMotion(), node_id + 1, "tilt", serial + "-T", tilt_limits_deg),
        }
        self.network: canopen.Network | None = None
        self._own_bus = False
        self._silent: set[str] = set()
        self._sdo_off: set[str] = set()  # drives whose SDO server is unsubscribed (silent or NMT STOPPED)
        if bus is not None:
            self.attach(bus)

    @property
    def rotation(self) -> AxisMotion:
        return self.drives["rotation"].motion

    @property
    def tilt(self) -> AxisMotion:
        return self.drives["tilt"].motion

    def attach(self, bus: can.BusABC | str) -> None:
        """Put both drives on ``bus`` (or on a new python-can virtual bus on channel ``bus``)."""
        if self.network is not None:
            raise RuntimeError("rate table sim is already attached to a bus")
        if isinstance(bus, str):
            bus = can.Bus(interface="virtual", channel=bus, receive_own_messages=False)
        self._own_bus = True
        net = canopen.Network(bus)
        net.NOTIFIER_CYCLE = NOTIFIER_CYCLE_S
        for drive in self.drives.values():
            net.add_node(drive.node)
        connect_network(net)
        net.subscribe(SYNC_COB_ID, self._on_sync)
        net.subscribe(NMT_COB_ID, self._on_nmt)  # after the LocalNodes' own NMT handlers
        self.network = net
        for drive in self.drives.values():
            self._boot(drive)
            self._update_sdo(drive)

    @staticmethod
    def _boot(drive: AxisDrive) -> None:
        """CiA 301 power-on / reset: boot-up message (0x700 + id, ``00``), then PRE-OPERATIONAL."""
        drive.node.nmt.send_command(NMT_RESET_COMMUNICATION)  # canopen sends the boot-up message
        drive.node.nmt.send_command(NMT_ENTER_PRE_OPERATIONAL)

    def _on_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        """NMT node control [command, node] (0 = all nodes), after canopen has set the NMT state."""
        if len(data) < 2:
            return
        command, node = data[0], data[1]
        for drive in self.drives.values():
            if node not in (0, drive.node.id):
                continue
            if command in (NMT_RESET_NODE, NMT_RESET_COMMUNICATION):
                self._boot(drive)
            self._update_sdo(drive)

    def _update_sdo(self, drive: AxisDrive) -> None:
        """Subscribe the drive's SDO server unless it is silent (fault hook) or NMT STOPPED."""
        if self.network is None:
            return
        want = drive.axis not in self._silent and drive.node.nmt.state != "STOPPED"
        if want and drive.axis in self._sdo_off:
            self.network.subscribe(drive.node.sdo.rx_cobid, drive.node.sdo.on_request)
            self._sdo_off.discard(drive.axis)
        elif not want and drive.axis not in self._sdo_off:
            self.network.unsubscribe(drive.node.sdo.rx_cobid, drive.node.sdo.on_request)
            self._sdo_off.add(drive.axis)

    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        """SYNC: every OPERATIONAL drive that answers sends its synchronous transmit PDOs (TPDO_MAP)."""
        net = self.network
        if net is None:
            return
        for drive in self.drives.values():
            if drive.axis in self._silent or drive.node.nmt.state != "OPERATIONAL":
                continue
            for base, mapped in drive.tpdos:
                payload = b"".join(var.encode_raw(drive.pdo_value(key)) for key, var in mapped)
                net.send_message(base + drive.node.id, payload)

    def close(self) -> None:
        """Detach from the bus (and shut it down if the sim opened it). Safe to call twice."""
        net, self.network = self.network, None
        if net is None:
            return
        if net.notifier is not None:
            net.notifier.stop(1.0)
        for drive in self.drives.values():
            drive.node.nmt.stop_heartbeat()
            drive.node.remove_network()
        if self._own_bus:
            net.bus.shutdown()

    # ---- fault hooks ------------------------------------------------------------------------
    def _axes(self, axis: str | None) -> list[AxisDrive]:
        if axis is None:
            return list(self.drives.values())
        if axis not in self.drives:
            raise ValueError(f"unknown axis {axis!r}; one of {', '.join(AXES)}")
        return [self.drives[axis]]

    def inject(self, fault: str, **params) -> None:
        """Inject ``fault`` (see the module docstring for names and parameters)."""
        axis = params.pop("axis", None)
        if fault == "sdo_abort":
            spec = {"code": int(params.pop("code", ABORT_DEFAULT_INJECTED)), "index": params.pop("index", None),
                    "count": params.pop("count", None)}
            for d in self._axes(axis):
                d.aborts = dict(spec)
        elif fault == "silent":
            for d in self._axes(axis):
                self._silent.add(d.axis)
                self._update_sdo(d)
        elif fault == "error_frames":
            count = int(params.pop("count", 10))
            if self.network is None:
                raise RuntimeError("error_frames needs the sim attached to a bus")
            for _ in range(count):
                self.network.bus.send(can.Message(is_error_frame=True, arbitration_id=0, is_extended_id=False))
        elif fault == "stuck":
            for d in self._axes(axis or "rotation"):
                d.set_stuck(True)
        elif fault == "fault":
            code = int(params.pop("code", EMCY_OVER_CURRENT))
            for d in self._axes(axis or "rotation"):
                d.enter_fault(code)
        elif fault == "warning":
            for d in self._axes(axis or "rotation"):
                d.warning = True
        else:
            raise ValueError(f"unknown fault {fault!r}: sdo_abort, silent, error_frames, stuck, fault, warning")
        if params:
            raise ValueError(f"unknown parameter(s) for {fault}: {', '.join(sorted(params))}")

    def clear_faults(self) -> None:
        """Undo every injected condition except a latched drive FAULT (the host resets that)."""
        for d in self.drives.values():
            d.aborts = None
            d.set_stuck(False)
            d.warning = False
            self._silent.discard(d.axis)
            self._update_sdo(d)

    def describe(self) -> dict[str, str]:
        """States of both drives, for logs and tests."""
        return {name: d.state for name, d in self.drives.items()}

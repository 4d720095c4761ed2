"""``bench instruments check``: connect to every instrument of a config, identify it, read one value.

Each instrument is opened on its own, so one that does not answer cannot hide the others. The
reading is chosen not to change the instrument's state (no motion, no power, no set point).

A failure comes back as one short problem and one hint saying what to do (docs/hardware.md):
before anything is opened on hardware, the instrument's endpoints are looked at (a serial device
that does not exist or that this user may not open, a CAN interface that is missing or down);
after a failed open or identify, the error is classified (permission, no such port, no SocketCAN,
Modbus TCP refused, no answer, a wrong answer).
"""

from __future__ import annotations

import errno
import glob
import grp
import os
import pwd
import re
from dataclasses import dataclass
from typing import Any, Iterator

from bench.config import LabConfig, InstrumentConfig
from bench.kinds import registry as kinds
from bench.errors import KNOWN_ERRORS, DeviceFault, InstrumentTimeout, NotConfigured, ProtocolError

HARDWARE_DOC = "docs/hardware.md"

SLCAN_BITRATE_CODES = {10_000: 0, 20_000: 1, 50_000: 2, 100_000: 3, 125_000: 4, 250_000: 5, 500_000: 6, 800_000: 7, 1_000_000: 8}
"""CAN bit rate (bit/s) -> the ``-sN`` code of ``slcand`` (LAWICEL ``S0``..``S8``)."""

MAX_PORTS_LISTED = 8
"""At most this many serial ports are named in a "no such port" hint ('bench lab init' lists all)."""

DEFAULT_CAN_BITRATE = 500_000
"""Bit rate (bit/s) suggested when the config's URL gives none: the rate table's drives (docs/rate-table.md)."""



@dataclass
class CheckRow:
    """One instrument's result: ``status`` is ``ok`` or the problem, ``hint`` what to do about it."""

    instrument: str
    transport: str
    endpoint: str
    identity: str
    reading: str
    status: str
    hint: str = ""

    @property
    def ok(self) -> bool:
        return self.status == "ok"


@dataclass(frozen=True)
class SerialPort:
    """A serial port this computer has: device path, USB description, vendor and product ids,
    serial number and its stable ``/dev/serial/by-id`` path (``""`` where unknown)."""

    device: str
    description: str = ""
    vid: int | None = None
    pid: int | None = None
    serial_number: str = ""
    by_id: str = ""

    @property
    def vid_pid(self) -> str:
        """``0403:6001`` style, ``""`` for a port that is not on USB."""
        return f"{self.vid:04x}:{self.pid:04x}" if self.vid is not None and self.pid is not None else ""

    def describe(self) -> str:
        """``/dev/ttyUSB0 (FT232R USB UART, 0403:6001, /dev/serial/by-id/...)``."""
        details = [d for d in (self.description if self.description not in ("", "n/a") else "", self.vid_pid, self.by_id) if d]
        return f"{self.device} ({', '.join(details)})" if details else self.device


def list_serial_ports() -> list[SerialPort]:
    """The serial ports pyserial sees (``serial.tools.list_ports``), with their by-id paths."""
    from serial.tools import list_ports

    by_id = {os.path.realpath(p): p for p in sorted(glob.glob("/dev/serial/by-id/*"))}
    return [SerialPort(p.device, p.description or "", p.vid, p.pid, p.serial_number or "", by_id.get(os.path.realpath(p.device), ""))
            for p in sorted(list_ports.comports(), key=lambda p: p.device)]


def default_serial_group(os_release: str) -> str:
    """The group that owns serial devices on this distribution, from ``/etc/os-release`` text:
    ``uucp`` on Arch and its derivatives, ``dialout`` elsewhere (Debian, Ubuntu, Fedora, SUSE)."""
    ids: set[str] = set()
    for line in os_release.splitlines():
        key, _, value = line.partition("=")
        if key.strip() in ("ID", "ID_LIKE"):
            ids.update(value.strip().strip('"').split())
    return "uucp" if "arch" in ids else "dialout"


def serial_group(path: str) -> str:
    """The group a user must be in to open the serial device ``path``: its own group when that is
    not root's, else the distribution's default (:func:`default_serial_group`)."""
    try:
        gid = os.stat(path).st_gid
        if gid != 0:
            return grp.getgrgid(gid).gr_name
    except (OSError, KeyError):
        pass
    try:
        with open("/etc/os-release", encoding="utf-8") as fh:
            return default_serial_group(fh.read())
    except OSError:
        return "dialout"


# ---- endpoints and their hints -------------------------------------------------------------------
@dataclass(frozen=True)
class Endpoint:
    """Something an instrument is reached through: a serial device path, a SocketCAN interface or
    a TCP address; ``option`` is the config key it comes from (``port``, ``gauge_port``)."""

    kind: str  # "serial" | "socketcan" | "tcp"
    address: str
    option: str = "port"
    bitrate: int = DEFAULT_CAN_BITRATE
    """socketcan: the bit rate of the URL (bit/s), or the default."""


def endpoints(inst: InstrumentConfig) -> list[Endpoint]:
    """The hardware endpoints of ``inst``'s links (``port`` and what its kind adds: a chamber's
    ``gauge_port``); URLs that need no device (``sim://``, ``loop://``, ``socket://``) give none."""
    return [ep for option, url in inst.ports() for ep in _endpoints_of(url, option)]


def _endpoints_of(url: str, option: str) -> Iterator[Endpoint]:
    if url.startswith("can://"):
        from drivers.can_transport import parse_can_url

        try:
            u = parse_can_url(url)
        except KNOWN_ERRORS:
            return
        if u.interface == "socketcan":
            yield Endpoint("socketcan", u.channel, option, int(u.options.get("bitrate") or DEFAULT_CAN_BITRATE))
        elif u.interface == "slcan" and _is_device_path(u.channel):
            yield Endpoint("serial", u.channel, option)
    elif url.startswith("modbus-"):
        from drivers.watlow_f4 import parse_modbus_url

        try:
            kind, where, tcp_port, _unit = parse_modbus_url(url)
        except ValueError:
            return
        if kind == "tcp":
            yield Endpoint("tcp", f"{where}:{tcp_port}", option)
        elif _is_device_path(where):
            yield Endpoint("serial", where, option)
    elif _is_device_path(url):
        yield Endpoint("serial", url, option)


def _is_device_path(s: str) -> bool:
    return s.startswith("/") and "://" not in s


def hint_no_port(path: str) -> str:
    """What to do about a serial device that does not exist: the ports there are, by-id paths."""
    ports = list_serial_ports()
    if not ports:
        return (f"no serial ports found on this computer: plug the adapter in and check 'dmesg | tail' for its "
                f"ttyUSB/ttyACM name ({HARDWARE_DOC})")
    shown = "; ".join(p.describe() for p in ports[:MAX_PORTS_LISTED])
    if len(ports) > MAX_PORTS_LISTED:
        shown += f"; and {len(ports) - MAX_PORTS_LISTED} more"
    return (f"serial ports here: {shown}; put the instrument's /dev/serial/by-id/... path in the config "
            f"(stable across replugs; 'bench lab init' lists them)")


def hint_permission(path: str) -> str:
    """What to do about a serial device this user may not open: the group to join."""
    group = serial_group(path)
    user = _user()
    try:
        members = grp.getgrnam(group)
        in_group = user in members.gr_mem or pwd.getpwnam(user).pw_gid == members.gr_gid
        in_session = members.gr_gid in os.getgroups()
    except KeyError:
        in_group = in_session = False
    if in_group and not in_session:
        return f"{user} is in group {group} but this login session is not yet: log out and log in again (or 'newgrp {group}')"
    return f"join the group that owns {path}: sudo usermod -aG {group} $USER, then log out and log in again ({HARDWARE_DOC})"


def hint_can_missing(iface: str, bitrate: int) -> str:
    """How to bring up a SocketCAN interface that does not exist (native adapter or SLCAN)."""
    code = SLCAN_BITRATE_CODES.get(bitrate, 6)
    return (f"plug in the USB-CAN adapter and bring it up: sudo ip link set {iface} up type can bitrate {bitrate}; "
            f"an SLCAN adapter (CANable, USBtin) first needs: sudo slcand -o -c -s{code} /dev/ttyACM0 {iface} "
            f"(or use port can://slcan/DEVICE?bitrate={bitrate}&node=N) ({HARDWARE_DOC})")


def hint_timeout(inst: InstrumentConfig, endpoint: Endpoint | None) -> str:
    """What to check when an instrument opened but did not answer."""
    if (endpoint is not None and endpoint.kind == "socketcan") or inst.port.startswith("can://"):
        return ("check the CAN bit rate (every node and the interface the same), the node ids (?node=N), 120 Ω "
                "termination at both ends of the bus, and that the drives are powered")
    note = inst.kind.timeout_note
    powered = ""
    if inst.powered_by is not None:
        powered = (f"; it is powered by {inst.powered_by.instrument} output {inst.powered_by.output}, which a check "
                   "does not switch on: switch it on first")
    if endpoint is not None and endpoint.kind == "tcp":
        return ("the gateway answered nothing: check the unit id (?unit=N) and the gateway's serial side, wiring and power"
                + (f"; {note}" if note else "") + powered)
    return (f"check the baud rate (config: {inst.baudrate} bit/s, must match the instrument), the wiring (TX/RX, "
            f"ground; RS-485 A/B) and that the instrument is powered" + (f"; {note}" if note else "") + powered)


def preflight(inst: InstrumentConfig) -> tuple[str, str] | None:
    """(problem, hint) for an endpoint of ``inst`` that cannot work as configured (a missing or
    forbidden serial device, a missing or down CAN interface), None if nothing is seen wrong."""
    for ep in endpoints(inst):
        where = "" if ep.option == "port" else f" ({ep.option})"
        if ep.kind == "serial":
            if not os.path.exists(ep.address):
                return f"no such port {ep.address}{where}", hint_no_port(ep.address)
            if not os.access(ep.address, os.R_OK | os.W_OK):
                return f"permission denied on {ep.address}{where}", hint_permission(ep.address)
        elif ep.kind == "socketcan" and os.path.isdir("/sys/class/net"):
            if not os.path.exists(f"/sys/class/net/{ep.address}"):
                return f"no CAN interface {ep.address}", hint_can_missing(ep.address, ep.bitrate)
            if _read(f"/sys/class/net/{ep.address}/operstate") == "down":
                return (f"CAN interface {ep.address} is down",
                        f"bring it up: sudo ip link set {ep.address} up type can bitrate {ep.bitrate} ({HARDWARE_DOC})")
    return None


def diagnose_failure(inst: InstrumentConfig, exc: BaseException) -> tuple[str, str]:
    """(problem, hint) for an error raised while opening, identifying or reading ``inst``."""
    eps = endpoints(inst)
    first = {ep.kind: ep for ep in reversed(eps)}
    code = _errno(exc)
    text = _innermost_text(exc)
    if code in (errno.EACCES, errno.EPERM) and "serial" in first:
        return f"permission denied on {first['serial'].address}", hint_permission(first["serial"].address)
    if code == errno.ENOENT and "serial" in first:
        return f"no such port {first['serial'].address}", hint_no_port(first["serial"].address)
    if code == errno.EAFNOSUPPORT and "socketcan" in first:
        return ("this kernel has no SocketCAN (address family not supported)",
                f"load it: sudo modprobe can_raw (in a container or WSL use an SLCAN adapter: port "
                f"can://slcan/DEVICE?bitrate={first['socketcan'].bitrate}&node=N) ({HARDWARE_DOC})")
    if code == errno.ENODEV and "socketcan" in first:
        return f"no CAN interface {first['socketcan'].address}", hint_can_missing(first["socketcan"].address, first["socketcan"].bitrate)
    if "tcp" in first and (code == errno.ECONNREFUSED or "cannot connect" in str(exc) or "refused" in str(exc)):
        host = first["tcp"].address
        return (f"connection refused by {host}",
                f"check host and port of the Modbus TCP gateway in the config (modbus-tcp://HOST:PORT; the standard "
                f"port is 502), that it is powered and on this network (ping {host.rsplit(':', 1)[0]})")
    if isinstance(exc, NotConfigured):
        return text, exc.fix
    if any(isinstance(e, InstrumentTimeout) for e in _chain(exc)):
        return f"no answer within {inst.timeout_s:g} s", hint_timeout(inst, eps[0] if eps else None)
    if isinstance(exc, ProtocolError):
        return (f"unexpected answer: {text}",
                f"something answered, but not as a {inst.driver}: is this the right instrument on this port, at the right baud rate?")
    if isinstance(exc, DeviceFault):
        return f"the instrument reports a fault: {text}", "see the instrument's display and manual; clear the fault and check again"
    return text, f"run 'bench --debug instruments check ...' for the full error ({HARDWARE_DOC})"


def _chain(exc: BaseException | None) -> Iterator[BaseException]:
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        yield exc
        exc = exc.__cause__ or exc.__context__


_ERRNO_TEXT = re.compile(r"\[Errno (\d+)\]")


def _errno(exc: BaseException) -> int | None:
    """The innermost OS error number of ``exc``'s chain (also from an ``[Errno N]`` in a message)."""
    found = None
    for e in _chain(exc):
        if isinstance(e, OSError) and isinstance(e.errno, int):
            found = e.errno
        elif isinstance(e, OSError) and e.args and isinstance(e.args[0], int):
            found = e.args[0]
    if found is None:
        m = _ERRNO_TEXT.findall(str(exc))
        found = int(m[-1]) if m else None
    return found


def _innermost_text(exc: BaseException) -> str:
    """One short line for ``exc``: the OS error's own text where there is one (not the same
    ``[Errno N]`` repeated by every layer that wrapped it)."""
    for e in reversed(list(_chain(exc))):
        if isinstance(e, OSError) and e.strerror:
            return f"{e.strerror}" + (f": {e.filename}" if e.filename else "")
    return str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__


def _read(path: str) -> str:
    try:
        with open(path, encoding="ascii") as fh:
            return fh.read().strip()
    except OSError:
        return ""


def _user() -> str:
    try:
        return pwd.getpwuid(os.getuid()).pw_name
    except KeyError:
        return os.environ.get("USER", "")


# ---- readings ------------------------------------------------------------------------------------
def reading(inst: InstrumentConfig, drv: Any) -> str:
    """One reading that changes nothing, formatted with its units (the kind's ``reading``); ``""``
    for a kind that declares none."""
    return kinds.load(inst.kind.reading)(drv) if inst.kind.reading else ""


def transport_of(url: str) -> str:
    """Transport named by a port URL: ``modbus-tcp``, ``can``, ``serial`` (simulated or real)."""
    scheme = url.split("://", 1)[0] if "://" in url else ""
    if scheme.startswith("modbus"):
        return scheme
    if scheme == "can":
        return "can"
    return "serial"


def check_instruments(config: LabConfig, *, sim: bool) -> list[CheckRow]:
    """One :class:`CheckRow` per instrument in ``config``; never raises for an instrument fault."""
    from bench.lab import open_lab

    rows = []
    for name, inst in config.instruments.items():
        endpoint = inst.port
        problem = None if sim else preflight(inst)
        if problem is not None:
            rows.append(CheckRow(name, transport_of(endpoint), endpoint, "", "", *problem))
            continue
        try:
            lab = open_lab(config, [name], sim=sim, realtime=False)
        except (*KNOWN_ERRORS, OSError, ValueError) as exc:
            rows.append(CheckRow(name, transport_of(endpoint), endpoint, "", "", *diagnose_failure(inst, exc)))
            continue
        identity = value = hint = ""
        try:
            drv = lab.instruments[name]
            endpoint = lab.ports[name]
            ident = drv.identify()
            identity = " ".join(str(ident.get(k, "")) for k in ("vendor", "model", "serial") if ident.get(k))
            value = reading(inst, drv)
            status = "ok"
        except (*KNOWN_ERRORS, OSError, ValueError, KeyError) as exc:
            status, hint = diagnose_failure(inst, exc)
        finally:
            lab.close()
        rows.append(CheckRow(name, transport_of(endpoint), endpoint, identity, value, status, hint))
    return rows

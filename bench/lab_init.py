"""``bench lab init``: a lab config skeleton from the serial ports and CAN interfaces of this computer.

One instrument entry per serial port (its USB description, VID:PID and the stable
``/dev/serial/by-id`` path as ``port``) and per SocketCAN interface, each with ``driver: CHOOSE``
and the installed kinds to choose from (with what each kind says about its set-up), a commented ``sim:`` section, and the station name. The file
is YAML that :func:`bench.config.load_config` accepts once every driver is chosen (and the entries
of ports that are no instrument are deleted); until then the loader names each entry still to
choose. See docs/hardware.md.
"""

from __future__ import annotations

import json
import os
import re
import socket
from datetime import datetime, timezone

from bench import __version__
from bench.config import CONFIG_SCHEMA
from bench.kinds import registry
from bench.identity import check_identity_text
from bench.instruments_check import SerialPort

CHOOSE = "CHOOSE"
"""The placeholder driver of every entry (not a driver: the loader refuses it until replaced)."""



def standard_names() -> list[str]:
    """Instrument names the procedure library uses (configs/sim.yaml): each kind's ``standard_name``."""
    return [k.standard_name for k in registry.kinds().values() if k.standard_name]


ARPHRD_CAN = "280"
"""``/sys/class/net/NAME/type`` of a CAN interface (linux/if_arp.h)."""

def looks_like() -> dict[int, str]:
    """USB vendor id -> what such a port usually is on this bench (each kind's ``usb_ids``; a comment
    in the skeleton, never a choice)."""
    out: dict[int, str] = {}
    for k in registry.kinds().values():
        for vid, what in k.usb_ids:
            out.setdefault(vid, what)
    return out


def can_interfaces() -> list[str]:
    """Names of the SocketCAN interfaces of this computer (``/sys/class/net``), sorted."""
    try:
        names = os.listdir("/sys/class/net")
    except OSError:
        return []
    out = []
    for name in sorted(names):
        try:
            with open(f"/sys/class/net/{name}/type", encoding="ascii") as fh:
                if fh.read().strip() == ARPHRD_CAN:
                    out.append(name)
        except OSError:
            continue
    return out


def default_station() -> str:
    """The station name when none is given: the host name (as ``bench run`` records it)."""
    return socket.gethostname() or "station-1"


def skeleton(ports: list[SerialPort], cans: list[str], station: str) -> str:
    """The config text for ``ports`` and CAN interfaces ``cans`` at ``station``."""
    station = check_identity_text(station, None, "--station")
    stamp = datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%MZ")
    choices = " | ".join(registry.kinds())
    lines = [
        f"# Lab config skeleton written by `bench lab init` on {_comment(socket.gethostname())} at {stamp} (bench {__version__}).",
        "# For every instrument entry below:",
        f"#   1. choose its driver: {choices}",
        "#      (and delete the entries of ports that are not instruments of this bench);",
        f"#   2. rename it to the name the procedures use: {', '.join(standard_names())};",
        "#   3. check baudrate and timeout against the instrument's own settings; add this lab's limits,",
        "#      e.g. limits: {set_point: [-30 degC, 80 degC]} (docs/procedures.md, \"Limits\").",
        "# Then: bench instruments check --config THIS_FILE   (docs/hardware.md; every key: configs/lab.example.yaml)",
        f"schema: {CONFIG_SCHEMA}",
        f"name: {_scalar(station)}",
        f"station: {_scalar(station)}                # recorded in every run file",
        "mode: hardware",
        "# world:                          # the lab's environment: fill in before analysing runs",
        "#   ambient_temp: 20 degC",
        "#   latitude: 36.4 deg             # geocentric latitude: Earth rate on the sensor axes",
        "#   magnetic_field: [23.6 uT, 0 uT, -42.0 uT]   # north, west, up",
        "instruments:",
    ]
    for port in ports:
        lines += _serial_entry(port, choices)
    for iface in cans:
        lines += _can_entry(iface, choices)
    if not ports:
        lines += ["  # no serial ports were found on this computer: plug the instruments in (dmesg | tail shows",
                  "  # the new ttyUSB/ttyACM device), then run bench lab init again" + ("" if cans else ", or fill this in:")]
    if not ports and not cans:
        lines += [
            "  instrument_1:",
            f"    driver: {CHOOSE}                  # {choices}",
            "    port: /dev/serial/by-id/CHANGE-ME",
            "    # sim: {backend: SAME_AS_DRIVER}   # uncomment for dry-runs of this lab with --sim",
        ]
    lines += ["recorder:", "  flush_interval: 1 s", ""]
    return "\n".join(lines)


def _serial_entry(port: SerialPort, choices: str) -> list[str]:
    about = ", ".join(x for x in (port.description if port.description not in ("", "n/a") else "",
                                   f"USB {port.vid_pid}" if port.vid_pid else "",
                                   f"serial {port.serial_number}" if port.serial_number else "") if x)
    lines = [f"  # {port.device}" + (f": {_comment(about)}" if about else "")]
    seen = looks_like()
    if port.vid is not None and port.vid in seen:
        lines.append(f"  # looks like {seen[port.vid]}")
    path = port.by_id or port.device
    if port.by_id:
        stable = f"= {port.device} now; the by-id path survives replugs"
    elif port.vid is not None:
        stable = "no /dev/serial/by-id path: a udev rule gives it a stable name (docs/hardware.md)"
    else:
        stable = "a built-in serial port: its name is stable"
    lines += [
        f"  {_key(port.device)}:",
        f"    driver: {CHOOSE}                  # {choices}",
        f"    port: {_scalar(path)}   # {stable}",
        *(f"    # {k.config_hint}" for k in registry.kinds().values() if k.config_hint),
        f"    # baudrate: 115200              # bit/s; default 115200{_other_baud_rates()}",
        "    timeout: 0.5 s",
        "    # sim: {backend: SAME_AS_DRIVER}   # uncomment for dry-runs of this lab with --sim (configs/sim.yaml)",
    ]
    return lines


def _other_baud_rates() -> str:
    """``, tvac 9600``: the kinds whose serial link defaults to another rate."""
    return "".join(f", {k.name} {k.baudrate}" for k in registry.kinds().values() if k.baudrate != 115200)


def _can_entry(iface: str, choices: str) -> list[str]:
    return [
        f"  # SocketCAN interface {iface}: the rate table's two CiA 402 drives (nodes 1 and 2), or the board over CAN",
        f"  {_key(iface)}:",
        f"    driver: {CHOOSE}                  # {choices}",
        f"    port: can://socketcan/{iface}?node=1",
        "    timeout: 0.5 s",
        "    # sim: {backend: SAME_AS_DRIVER}   # uncomment for dry-runs of this lab with --sim (configs/sim.yaml)",
    ]


_PLAIN = re.compile(r"[A-Za-z0-9_./+=?&@-][A-Za-z0-9_./:+=?&@ -]*")


def _scalar(text: str) -> str:
    """``text`` as a YAML scalar: plain where that reads back unchanged, else double-quoted."""
    if _PLAIN.fullmatch(text) and not text.endswith((" ", ":")) and ": " not in text and " #" not in text:
        return text
    return json.dumps(text)  # a JSON string is a YAML double-quoted scalar


def _key(device: str) -> str:
    """An instrument name from a device path or interface: ``/dev/ttyUSB0`` -> ``ttyUSB0``."""
    name = re.sub(r"[^A-Za-z0-9_]", "_", os.path.basename(device)) or "instrument"
    return name if not name[0].isdigit() else f"port_{name}"


def _comment(text: str) -> str:
    return " ".join(text.split())  # one line, whatever the USB strings hold

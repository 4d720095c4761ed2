"""Driver of a Pfeiffer TPG 261 vacuum gauge controller (RS-232, mnemonic protocol).

Protocol (``../shared/protocols.md`` section 2, manual BG 5195 BEN/A pp. 65-75 [V]): 9600 baud
8N1 without handshake; ``MNE[,params]<CR><LF>`` -> ``<ACK><CR><LF>`` or ``<NAK><CR><LF>``,
then ``<ENQ>`` -> ``data<CR><LF>``. At :meth:`Tpg261.open` the driver sends ``<ETX>`` (ends the
power-up continuous mode and clears the unit's input buffer), drops what the port holds, then
sets the unit to Torr (``UNI,1``) and reads it back. Lines that are neither ACK nor NAK while
waiting for one (a reading still streaming in) are skipped within the byte budget.

Pressure status (``PR1`` -> ``s,x.xxxxE±xx``): 0 ok -> the value; 1 underrange -> the value
(the gauge's lower range end, so the pressure is *at most* that) with ``status=1`` in
:meth:`read_pressure`; 2..6 -> :class:`DeviceFault` naming the status.
Errors: NAK -> :class:`ProtocolError` (with the ``ERR`` word when it can be read); no answer
-> :class:`InstrumentTimeout`; an answer that is not ``s,x.xxxxE±xx`` -> :class:`ProtocolError`.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Callable

import serial

from drivers.base import Driver, check_timeout
from drivers.errors import DeviceFault, InstrumentError, ProtocolError
from drivers.transport import LineChannel, open_serial

ACK, NAK, ENQ, ETX = b"\x06", b"\x15", b"\x05", b"\x03"
EOL = b"\r\n"
BAUDRATE = 9600  # factory setting, p. 65 [V]
UNITS = {0: "mbar", 1: "Torr", 2: "Pa"}  # UNI codes, p. 73 [V]
TORR_PER = {0: 0.750061683, 1: 1.0, 2: 0.00750061683}  # Torr per mbar / Torr / Pa
STATUS = {  # PR1 status digit, p. 71 [V]
    0: "ok",
    1: "underrange",
    2: "overrange",
    3: "sensor error",
    4: "sensor off",
    5: "no sensor",
    6: "identification error",
}
# p. 71: "x,sx.xxxxEsxx"; the same page prints "5,2.0000E-2" (one exponent digit), so 1-3 are taken
_PR_RE = re.compile(r"^([0-9]),\s*([+-]?[0-9]\.[0-9]{4}E[+-][0-9]{1,3})$")


@dataclass(frozen=True)
class PressureReading:
    """One PR1 reading: pressure (Torr) and the gauge status (0 ok, 1 underrange = at most this)."""

    torr: float
    status: int

    @property
    def status_text(self) -> str:
        return STATUS.get(self.status, f"status {self.status}")


def parse_pr_reply(raw: bytes) -> tuple[int, float]:
    """(status, value in the current unit) of a ``PR1`` answer line (with or without CR/LF).

    Any other byte string raises :class:`ProtocolError` (never another exception).
    """
    try:
        text = raw.decode("ascii").strip("\r\n")
    except UnicodeDecodeError:
        raise ProtocolError(f"pressure gauge: non-ASCII answer {raw!r}") from None
    m = _PR_RE.match(text)
    if m is None:
        raise ProtocolError(f"pressure gauge: answer {text!r} is not 's,x.xxxxE±xx'")
    return int(m.group(1)), float(m.group(2))


class MnemonicChannel(LineChannel):
    """The ACK/ENQ exchange on a serial port: :class:`drivers.transport.LineChannel`'s bounded
    line reads (timeout and byte budget) and traffic reporting, with the TPG's handshake."""

    def __init__(self, port: serial.SerialBase, timeout_s: float, name: str,
                 on_traffic: Callable[[str, str, bytes], None] | None = None):
        super().__init__(port, timeout_s, name, on_traffic, eol=EOL)

    def clear(self) -> None:
        """``<ETX>`` (clears the unit's input, ends continuous mode), then drop what we hold."""
        self.send_realtime(ETX)
        self._rx.clear()
        try:
            self.port.reset_input_buffer()
        except serial.SerialException as exc:
            raise InstrumentError(f"{self.name}: flushing the port failed: {exc}") from None

    def query(self, mnemonic: str) -> bytes:
        """Send ``mnemonic``, expect ACK, send ENQ; return the data line (without CR/LF).

        NAK -> :class:`ProtocolError`; nothing -> :class:`InstrumentTimeout`.
        """
        self.command(mnemonic)
        self.send_realtime(ENQ)
        return self._read_line(mnemonic, self._budget())[0].encode("ascii", "replace")

    def command(self, mnemonic: str) -> None:
        """Send ``mnemonic`` and wait for ACK, skipping other lines (readings still streaming in)."""
        self._rx.clear()
        self.send(mnemonic)
        budget = self._budget()
        while True:
            line, budget = self._read_line(mnemonic, budget)
            if line == ACK.decode():
                return
            if line == NAK.decode():
                raise ProtocolError(f"{self.name}: NAK (refused) for {mnemonic!r}")


class Tpg261(Driver):
    """TPG 261 gauge channel 1. Pressures in Torr whatever the unit's display unit."""

    kind = "tpg261"
    streams = False

    def __init__(self, port: serial.SerialBase, *, timeout_s: float = 0.5,
                 on_traffic: Callable[[str, str, bytes], None] | None = None, name: str = "pressure gauge"):
        self.port = port
        self.name = name
        self.timeout_s = check_timeout(timeout_s)
        self.channel = MnemonicChannel(port, self.timeout_s, name, on_traffic)
        self.unit = 1

    @classmethod
    def open(cls, url: str, *, baudrate: int = BAUDRATE, timeout_s: float = 0.5,
             on_traffic: Callable[[str, str, bytes], None] | None = None) -> "Tpg261":
        """Open ``url`` (``/dev/ttyUSB1``, ``sim://tvac.gauge``), end continuous mode, set Torr."""
        gauge = cls(open_serial(url, baudrate, timeout_s), timeout_s=timeout_s, on_traffic=on_traffic,
                    name=f"pressure gauge {url}")
        try:
            gauge.channel.clear()
            gauge.set_units(1)
        except BaseException:
            gauge.close()
            raise
        return gauge

    def close(self) -> None:
        self.port.close()

    def _text(self, mnemonic: str) -> str:
        raw = self.channel.query(mnemonic)
        try:
            return raw.decode("ascii")
        except UnicodeDecodeError:
            raise ProtocolError(f"{self.name}: non-ASCII answer {raw!r} to {mnemonic}") from None

    def _nak_detail(self, mnemonic: str) -> str:
        try:
            return self._text("ERR")
        except InstrumentError:
            return "unknown"

    def command(self, mnemonic: str) -> str:
        """Any request; returns its data line. NAK -> :class:`ProtocolError` with the ERR word."""
        try:
            return self._text(mnemonic)
        except ProtocolError as exc:
            if "NAK" not in str(exc):
                raise
            raise ProtocolError(f"{self.name}: NAK for {mnemonic!r} (ERR word {self._nak_detail(mnemonic)})") from None

    def set_units(self, code: int) -> None:
        """Display/transfer unit: 0 mbar, 1 Torr, 2 Pa; verified by reading ``UNI`` back."""
        if code not in UNITS:
            raise ValueError(f"unit code must be one of {sorted(UNITS)}")
        self.command(f"UNI,{code}")
        self.unit = self.read_units()
        if self.unit != code:
            raise DeviceFault(f"{self.name}: unit is {UNITS.get(self.unit, self.unit)} after setting {UNITS[code]}")

    def read_units(self) -> int:
        text = self.command("UNI")
        if text not in ("0", "1", "2"):
            raise ProtocolError(f"{self.name}: UNI answered {text!r}")
        return int(text)

    def identify(self) -> dict[str, str]:
        """vendor, model, serial (not available over RS-232 [U]), firmware (``PNR``), gauges (``TID``)."""
        return {"vendor": "Pfeiffer Vacuum", "model": "TPG 261", "serial": "unknown",
                "firmware": self.command("PNR"), "gauges": self.command("TID")}

    def read_pressure(self) -> PressureReading:
        """Gauge 1 (``PR1``). Status 0/1 give a reading; 2..6 raise :class:`DeviceFault`."""
        status, value = parse_pr_reply(self.command("PR1").encode("ascii"))
        if status not in (0, 1):
            raise DeviceFault(f"{self.name}: gauge 1 reports {STATUS.get(status, f'status {status}')}")
        return PressureReading(value * TORR_PER[self.unit], status)

    def read_pressure_torr(self) -> float:
        """Gauge 1 pressure (Torr); underrange returns the range end (an upper bound)."""
        return self.read_pressure().torr

    def errors(self) -> str:
        """The ``ERR`` word (``0000`` = none) [U: VGC401 form]."""
        return self.command("ERR")

    def safe_state(self) -> str:
        """A gauge only measures: nothing to make safe."""
        return "nothing to make safe (measures only)"

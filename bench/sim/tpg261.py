"""Simulated Pfeiffer TPG 261 single-gauge controller with a PKR full-range gauge (RS-232).

Protocol (``../shared/protocols.md`` section 2, manual BG 5195 BEN/A pp. 65-75 [V]): the host
sends ``MNE[,params]<CR>[<LF>]``; the unit answers ``<ACK><CR><LF>`` (or ``<NAK><CR><LF>`` for
an unknown mnemonic or a bad parameter); the host then sends ``<ENQ>`` and gets
``data<CR><LF>``. ENQ again re-runs the last request (a fresh reading). ``<ETX>`` clears the
input buffer; spaces are ignored. At power-up the unit streams a reading every 1 s
until it receives its first character (``power_up_stream``, p. 65).

Served: ``PR1``/``PR2``/``PRX`` (``s,x.xxxxE±xx`` in the current unit), ``UNI[,x]`` (0 mbar,
1 Torr, 2 Pa; default Torr), ``TID`` (``PKR,noSEn``), ``PNR``, ``ERR`` (``0000``; ``0001``
after a syntax error, ``0010`` after a bad parameter [U, VGC401 form]), ``RES`` (``0``).
ENQ with no valid request answers the ``ERR`` word (p. 67). Pressure is the chamber's
``pressure_torr`` at the time of the ENQ; a PKR covers about 1e-9 mbar to atmosphere
(status 1 underrange below :data:`UNDERRANGE_MBAR`, 2 overrange above :data:`OVERRANGE_MBAR` [U]).
Values are always exponential; for logarithmic gauges (PKR, TPR, IKR, PBR, IMR) the 3rd and 4th
decimals are always 0 (p. 71-72). The power-up stream sends both channels, like ``COM``
(``x,sx.xxxxEsxx,y,sy.yyyyEsyy``, p. 72); channel 2 has no sensor.

Fault hooks (``inject(fault, **params)``, ``clear_faults()``):

* ``sensor_error``: PR1 status 3 ("sensor error"); ``status=N`` gives another status (4 off, 5 none...).
* ``garbage``: every ENQ is answered with ``data=`` bytes (default non-ASCII noise) instead.
* ``stall``: nothing is answered at all (no ACK, no data).
* ``stuck``: the pressure stays at its value at injection (or at ``torr=`` if given).
"""

from __future__ import annotations

from bench import __version__
from bench.sim.line_device import LineDeviceSim

ACK, NAK, ENQ, ETX = b"\x06", b"\x15", 0x05, 0x03
TORR_TO = {0: 1.0 / 0.750061683, 1: 1.0, 2: 133.322368}  # Torr -> mbar, Torr, Pa (1 mbar = 0.750062 Torr)
UNDERRANGE_MBAR = 1e-9  # PKR lower range end, the brief's "to 1e-9 mbar" [U]
OVERRANGE_MBAR = 1100.0  # our choice [U]: above atmosphere plus margin
STREAM_PERIOD_S = 1.0  # power-up continuous mode period, COM,1 (p. 72 [V])
GARBAGE = b"\xff\xfe#\x80?\r\n"
FAULTS = ("sensor_error", "garbage", "stall", "stuck")


LOGARITHMIC_GAUGES = frozenset({"TPR", "IKR9", "IKR11", "PKR", "PBR", "IMR"})  # CMR is linear
NO_SENSOR = "5,2.0000E-02"  # p. 71: "No sensor (output: 5,2.0000E-2 [mbar])", exponent as sxx


def format_pressure(status: int, value: float, logarithmic: bool = False) -> str:
    """``s,x.xxxxE±xx`` as sent by the TPG: always exponential; a logarithmic gauge's 3rd and 4th
    decimals are 0 (p. 71 [V]). The positive mantissa is sent without a sign [U]."""
    if logarithmic:
        mantissa, _, exponent = f"{value:.2E}".partition("E")
        return f"{status},{mantissa}00E{exponent}"
    return f"{status},{value:.4E}"


class Tpg261Sim(LineDeviceSim):
    """TPG 261 on ``clock``, reading ``chamber.pressure_torr(clock.now())``."""

    realtime_bytes = frozenset({ENQ, ETX})

    def __init__(self, clock, chamber, *, baudrate: int = 9600, units: int = 1, gauge_id: str = "PKR",
                 power_up_stream: bool = True):
        super().__init__(clock, baudrate)
        self.chamber = chamber
        self.units = units
        self.gauge_id = gauge_id
        self.faults: dict[str, dict] = {}
        self.streaming = power_up_stream
        self._next_stream_s = clock.now() + STREAM_PERIOD_S
        self._pending: str | None = None  # the last acknowledged request, answered on ENQ
        self.error_word = "0000"

    # ---- faults -----------------------------------------------------------------------------
    def inject(self, fault: str, **params) -> None:
        """Start ``fault`` (one of :data:`FAULTS`, parameters in the module docstring)."""
        if fault == "sensor_error":
            self.faults[fault] = {"status": int(params.get("status", 3))}
        elif fault == "garbage":
            self.faults[fault] = {"data": bytes(params.get("data", GARBAGE))}
        elif fault == "stall":
            self.faults[fault] = {}
        elif fault == "stuck":
            torr = params.get("torr")
            self.faults[fault] = {"torr": float(torr) if torr is not None else self.chamber.pressure_torr(self.clock.now())}
        else:
            raise ValueError(f"unknown fault {fault!r}; known: {', '.join(FAULTS)}")

    def clear_faults(self) -> None:
        self.faults.clear()

    # ---- protocol ---------------------------------------------------------------------------
    def pressure_torr(self) -> float:
        if "stuck" in self.faults:
            return self.faults["stuck"]["torr"]
        return self.chamber.pressure_torr(self.clock.now())

    def reading(self) -> str:
        """The PR1 data string now."""
        torr = self.pressure_torr()
        if "sensor_error" in self.faults:
            return format_pressure(self.faults["sensor_error"]["status"], 0.0)
        mbar = torr * TORR_TO[0]
        status = 1 if mbar < UNDERRANGE_MBAR else 2 if mbar > OVERRANGE_MBAR else 0
        return format_pressure(status, torr * TORR_TO[self.units], self.gauge_id in LOGARITHMIC_GAUGES)

    def receive(self, data: bytes) -> None:
        if data:
            self.streaming = False  # the first received character ends continuous mode (p. 65)
        super().receive(data)

    def on_realtime(self, byte: int) -> None:
        if "stall" in self.faults:
            return
        if byte == ETX:
            self._in.clear()
        elif byte == ENQ:
            if "garbage" in self.faults:
                self._out += self.faults["garbage"]["data"]
                return
            self.reply(self._data(self._pending) if self._pending else self.error_word)

    def on_line(self, line: str) -> None:
        if "stall" in self.faults:
            return
        line = line.replace(" ", "")  # spaces are ignored (p. 67)
        mnemonic, _, params = line.partition(",")
        mnemonic = mnemonic.upper()
        ok = self._accept(mnemonic, params)
        if ok:
            self._pending = line.upper()
            self._out += ACK + b"\r\n"
        else:
            self._pending = None
            self._out += NAK + b"\r\n"

    def _accept(self, mnemonic: str, params: str) -> bool:
        """Validate (and for UNI,x apply) a request; set the error word on failure."""
        if mnemonic in ("PR1", "PR2", "PRX", "TID", "PNR", "ERR", "RES") and not params:
            return True
        if mnemonic == "RES" and params == "1":
            return True
        if mnemonic == "UNI":
            if not params:
                return True
            if params in ("0", "1", "2"):
                self.units = int(params)
                return True
            self.error_word = "0010"
            return False
        self.error_word = "0001" if mnemonic not in ("PR1", "PR2", "PRX", "TID", "PNR", "ERR", "RES", "UNI") else "0010"
        return False

    def _data(self, request: str) -> str:
        mnemonic = request.partition(",")[0]
        if mnemonic == "PR1":
            return self.reading()
        if mnemonic == "PR2":
            return NO_SENSOR
        if mnemonic == "PRX":
            return f"{self.reading()},{NO_SENSOR}"
        if mnemonic == "UNI":
            return str(self.units)
        if mnemonic == "TID":
            return f"{self.gauge_id},noSEn"
        if mnemonic == "PNR":
            return f"SIM-{__version__}"
        if mnemonic == "ERR":
            word, self.error_word = self.error_word, "0000"
            return word
        return "0"  # RES: no error

    # ---- power-up continuous mode -----------------------------------------------------------
    def _stream_until(self, t_s: float) -> None:
        while self.streaming and self._next_stream_s <= t_s:
            self.reply(self._data("PRX"))  # both channels, as COM sends them (p. 72)
            self._next_stream_s += STREAM_PERIOD_S

    def take_output(self, t_s: float, max_bytes: int | None = None) -> bytes:
        with self._lock:
            self._stream_until(t_s)
            return super().take_output(t_s, max_bytes)

    def pending_bytes(self, t_s: float) -> int:
        with self._lock:
            self._stream_until(t_s)
            return super().pending_bytes(t_s)

    def next_output_time(self) -> float | None:
        if self._out:
            return self.clock.now()
        return self._next_stream_s if self.streaming else None

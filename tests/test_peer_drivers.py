"""Drivers written by others for the real devices, run against our simulators (issue 28, part 6).

Each peer is installed from the package index by the test extras (``pyproject.toml``) and skipped,
with the reason, where it cannot be imported. They face the simulated chamber controller as
``bench sim serve`` offers it to other processes: Modbus RTU on a pseudo-terminal.

* ``watlow-f4`` (anwar-lab-ucb/watlow_f4, on minimalmodbus): its whole API (PV, set point read,
  set point write with read-back). What it sends: FC 3 reads of registers 100 and 300, FC 16
  (minimalmodbus's default for ``write_register``) writes of 300, 9600 baud, unit 1.
* ``chamberconnectlibrary`` (Espec's WatlowF4 class): Python 2 only (``print`` statements in
  ``modbus.py``; it does not import on Python 3), so it is not run. The registers its
  single-loop calls read are sent here by ``minimalmodbus`` instead, as its source builds them
  (``watlowf4.py`` line numbers of version 2.2.5 below), and decoded as it decodes them.

docs/tvac.md ("Drivers written by others") lists what each found.
"""

from __future__ import annotations

import sys

import pytest

from tests.sim_serve import sim_serve
from tests.test_modbus_rtu import rtu_config

minimalmodbus = pytest.importorskip("minimalmodbus", reason="minimalmodbus (test extra) is not installed: peer Modbus RTU client not run")


@pytest.fixture(scope="module")
def served_pty(tmp_path_factory):
    """The simulated chamber controller on Modbus RTU behind a pseudo-terminal (``bench sim serve``)."""
    if sys.platform == "win32":
        pytest.skip("pseudo-terminals are POSIX")
    with sim_serve(rtu_config(tmp_path_factory.mktemp("peer")), "--instrument", "tvac") as served:
        yield served.endpoint("tvac")


def test_watlow_f4_package_reads_and_writes_the_simulated_controller(served_pty):
    watlow_f4 = pytest.importorskip("watlow_f4", reason="watlow-f4 (test extra) is not installed: peer F4 driver not run")
    f4 = watlow_f4.WatlowF4(served_pty)
    try:
        assert f4.temperature == pytest.approx(20.0, abs=0.1)  # the world's 20 degC ambient, in tenths on the wire
        f4.temperature_setpoint = 31.5  # FC 16 write of register 300, then its own read-back check
        assert f4.temperature_setpoint == 31.5
        with pytest.raises(ValueError, match="max"):  # its own limit check: nothing sent
            f4.temperature_setpoint = 140.0
        f4.temperature_setpoint = 20.0
    finally:
        f4.instrument.serial.close()


def test_the_registers_chamberconnectlibrary_reads_are_served(served_pty):
    """Espec's ``WatlowF4`` (loops=1): the reads of ``get_loop_sp`` (l. 328-331: 602, 300, 200),
    ``get_loop_pv`` (l. 352: 100), the input scalar (l. 111: 606, times 10), ``get_loop_range``
    (l. 358-359: 603, 602), ``get_loop_units`` (l. 394-396: 608, then 901), ``get_loop_power``
    (l. 424-425: 103, 107, raw/100), ``get_event`` (l. 536: 2000 + 10(N-1)) and the analog input
    set-up (l. 143-144: 600, 610), all FC 3, signed where it reads signed."""
    inst = minimalmodbus.Instrument(served_pty, 1)
    inst.serial.baudrate = 9600
    inst.serial.timeout = 1.0
    try:
        def holding(reg: int, signed: bool = False) -> int:
            return inst.read_register(reg, 0, functioncode=3, signed=signed)

        scalar = 1 / float(holding(606) * 10 or 1)  # its __get_scalar: 1 decimal -> 1/10
        assert scalar == 0.1
        minsp = holding(602, True) * scalar
        const = holding(300, True) * scalar
        assert holding(200) in (0, 1)  # constant set point: it does not read the profile's 4122
        maxsp = holding(603, True) * scalar
        assert (minsp, maxsp) == (-40.0, 100.0)  # the chamber's set-point limits (bench/model/chamber.py)
        assert minsp <= const <= maxsp
        assert holding(100, True) * scalar == pytest.approx(20.0, abs=0.1)
        units = ["Temp", "%RH", "PSI", ""][holding(608)]  # was exception 2 (illegal data address) before
        assert units == "Temp" and holding(901) == 1  # degrees Celsius
        assert 0 <= holding(103, True) / 100.0 + holding(107, True) / 100.0 <= 100.0
        assert [holding(2000 + 10 * (n - 1)) for n in (1, 2)] == [0, 0]  # pumps off, vent closed at start
        lookup = ["thermocouple", "rtd", "process", "wetbulb-drybulb", "off"]
        assert [lookup[holding(600)], lookup[holding(610)]] == ["thermocouple", "thermocouple"]
        with pytest.raises(minimalmodbus.IllegalRequestError):  # input 3 (620) does not exist on this chamber
            holding(620)
    finally:
        inst.serial.close()

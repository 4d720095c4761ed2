"""Golden exchanges of the GRBL 1.1-style stepper bench (docs/golden/grbl.md).

The byte strings are transcribed from gnea/grbl ``doc/markdown/interface.md`` (response, push and
status messages, error and alarm tables), ``doc/markdown/commands.md`` (realtime commands, ``$X``)
and, for the exact line ends of the welcome message, ``grbl/report.c``. Requests such as ``$N=300``
and ``$RUN`` are the bench firmware's own commands (docs/stepper-bench.md); their answers take
GRBL's forms. Nothing is produced by the project's encoders; no driver or simulator constant is
imported.

(a) driver: ``drivers.stepper_bench.StepperBench`` against a scripted port;
(b) simulator: ``bench.sim.stepper_bench.StepperBenchSim`` reached raw through ``sim://``.
"""

from __future__ import annotations

import itertools
import re

import pytest
import serial

from bench.clock import VirtualClock
from bench.config import load_config
from bench.sim import registry
from bench.sim.factory import build_devices
from drivers.errors import DeviceFault, InstrumentTimeout, ProtocolError
from drivers.stepper_bench import StepperBench
from tests.conftest import SIM_CONFIG
from tests.golden.expected_exchange import expected_exchange

TIMEOUT_S = 0.3  # driver and raw-port read timeout (s; virtual time for the simulator)

# ---- rows (docs/golden/grbl.md) ----------------------------------------------------------------
OK = b"ok\r\n"  # G1
VERSION = (b"$I\n", b"[VER:v1.1d.20161014:Some string]\r\n[OPT:VL]\r\nok\r\n")  # G2
STATUS_DOC = b"<Idle|MPos:0.000,0.000,0.000|FS:0.0,0>\r\n"  # G3, interface.md "Status Reporting"
STATUS_RUN = b"<Run|MPos:12.500,0.000,0.000|F:180|N:300>\r\n"  # G4: GRBL form + the firmware's N:
STATUS_HOLD = b"<Hold:0|MPos:12.500,0.000,0.000|F:0|N:300>\r\n"  # G5
WELCOME = b"\r\nGrbl 1.1f ['$' for help]\r\n"  # G8
ALARM_3 = b"ALARM:3\r\n"  # G9: reset while in motion
ALARM_LOCK_MSG = b"[MSG:'$H'|'$X' to unlock]\r\n"  # G9
UNLOCKED = b"[MSG:Caution: Unlocked]\r\nok\r\n"  # G10
# interface.md "Real-time Status Reports": <State[:sub]|MPos or WPos:x,y,z|optional fields>, CR LF
STATUS_RE = re.compile(rb"^<(Idle|Run|Hold:[01]|Jog|Alarm|Door:[0-3]|Check|Home|Sleep)"
                       rb"\|[MW]Pos:(-?[0-9]+\.[0-9]{3}),-?[0-9]+\.[0-9]{3},-?[0-9]+\.[0-9]{3}"
                       rb"((?:\|[A-Za-z]+:[^|<>\r\n]*)*)>\r\n$")
VERSION_RE = re.compile(rb"^\[VER:[^:\]\r\n]*:SIM-0002\]\r\n\[OPT:[^\]\r\n]*\]\r\nok\r\n$")


# ---- (a) driver ------------------------------------------------------------------------------
def bench_on(port) -> StepperBench:
    return StepperBench(port, timeout_s=TIMEOUT_S)


def test_driver_reads_the_version_line_and_skips_opt():
    with expected_exchange([VERSION], baudrate=115200) as port:
        ident = bench_on(port).identify()
    assert ident["firmware"] == "v1.1d.20161014" and ident["serial"] == "Some string"


def test_driver_status_in_grbl_form():
    """G4/G5: state (sub-state dropped), the X machine position as the angle (deg), n from N:."""
    with expected_exchange([(b"$S\n", STATUS_RUN + OK), (b"$S\n", STATUS_HOLD + OK)], baudrate=115200) as port:
        bench = bench_on(port)
        assert bench.status() == {"state": "Run", "n": 300, "angle_deg": 12.5}
        assert bench.status() == {"state": "Hold", "n": 300, "angle_deg": 12.5}


def test_driver_refuses_a_plain_grbl_status_without_n():
    """G3: the document's own report has no N: field: a plain GRBL is not this bench."""
    with expected_exchange([(b"$S\n", STATUS_DOC + OK)], baudrate=115200) as port:
        with pytest.raises(ProtocolError, match="no status report"):
            bench_on(port).status()


def test_driver_set_rate_and_run_are_acknowledged():
    """G1: every line is answered ok."""
    with expected_exchange([(b"$N=300\n", OK), (b"$RUN\n", OK)], baudrate=115200) as port:
        bench = bench_on(port)
        bench.set_rate(bench.calibration.speed_for_n(300))
        bench.run()


def test_driver_error_code_is_protocol_error_with_its_meaning():
    """G6: error:22 "Feed rate has not yet been set or is undefined" (run before a speed)."""
    with expected_exchange([(b"$RUN\n", b"error:22\r\n")], baudrate=115200) as port:
        with pytest.raises(ProtocolError, match=r"error:22 \(feed rate"):
            bench_on(port).run()


def test_driver_pushed_alarm_is_device_fault_and_stays_in_step():
    """G9 then G7: ALARM:3, the welcome message and the unlock hint arrive before the answer
    (error:9, locked out); the driver raises DeviceFault and the next command reads its own ok."""
    pushed = ALARM_3 + WELCOME + ALARM_LOCK_MSG
    with expected_exchange([(b"$RUN\n", pushed + b"error:9\r\n"), (b"$STOP\n", OK)], baudrate=115200) as port:
        bench = bench_on(port)
        with pytest.raises(DeviceFault, match=r"ALARM:3 \(reset while in motion"):
            bench.run()
        bench.stop()


def test_driver_safe_state_holds_then_stops():
    """G11: realtime ``!`` (no answer), then a confirmed stop."""
    with expected_exchange([(b"!", None), (b"$STOP\n", OK)], baudrate=115200) as port:
        bench_on(port).safe_state()


def test_driver_silent_bench_is_timeout():
    with expected_exchange([(b"$STOP\n", None)], baudrate=115200) as port:
        with pytest.raises(InstrumentTimeout):
            bench_on(port).stop()


# ---- (b) simulator -------------------------------------------------------------------------------
_names = itertools.count()


@pytest.fixture
def sim():
    """The configured stepper bench simulator on a virtual clock, and a raw port to it."""
    clock = VirtualClock()
    dev = build_devices(load_config(SIM_CONFIG), clock, ["stepper_bench"])["stepper_bench"].device
    name = f"golden.grbl.{next(_names)}"
    url = registry.register(name, dev)
    port = serial.serial_for_url(url, baudrate=115200, timeout=TIMEOUT_S)
    yield dev, clock, port
    port.close()
    registry.unregister(name)


def line(port) -> bytes:
    return port.read_until(b"\n")


def status(port) -> re.Match:
    port.write(b"?")  # realtime: no line end, answered at once, no ok
    m = STATUS_RE.match(line(port))
    assert m, "status report not in the documented form"
    return m


def test_sim_status_report_form_and_values(sim):
    dev, clock, port = sim
    m = status(port)
    assert m[1] == b"Idle" and float(m[2]) == 0.0
    port.write(b"$N=300\n$RUN\n")
    assert line(port) == OK and line(port) == OK
    clock.sleep(10.0)
    m = status(port)
    assert m[1] == b"Run" and float(m[2]) == pytest.approx(10.0 * dev.rate_dps(), abs=1e-3)


def test_sim_answers_ok_to_an_empty_line(sim):
    """G1: "If an empty line with only a return is sent to Grbl, it ... will return an ok"."""
    dev, clock, port = sim
    port.write(b"\n")
    assert line(port) == OK


@pytest.mark.parametrize("request_, answer", [
    (b"$WARP\n", b"error:3\r\n"),  # '$' system command not recognized or supported
    (b"$N=abc\n", b"error:2\r\n"),  # numeric value format is not valid
    (b"$RUN\n", b"error:22\r\n"),  # feed rate (speed) has not yet been set
    (b"$N=" + b"1" * 100 + b"\n", b"error:11\r\n"),  # max characters per line exceeded
])
def test_sim_error_codes(sim, request_, answer):
    dev, clock, port = sim
    port.write(request_)
    assert line(port) == answer
    assert not dev.running and dev.n == 0


def test_sim_feed_hold_and_resume(sim):
    """G11/G12: ``!`` holds (Hold:0, the table stops), ``~`` resumes."""
    dev, clock, port = sim
    port.write(b"$N=300\n$RUN\n")
    assert line(port) == OK and line(port) == OK
    port.write(b"!")
    m = status(port)
    assert m[1] == b"Hold:0"
    held_at = float(m[2])
    clock.sleep(5.0)
    assert float(status(port)[2]) == pytest.approx(held_at, abs=1e-9)
    port.write(b"~")
    assert status(port)[1] == b"Run"


def test_sim_reset_in_motion_raises_alarm_3_and_locks_until_unlocked(sim):
    """G8-G10: 0x18 while turning: ALARM:3, welcome message, unlock hint; $RUN is locked out
    (error:9) until $X."""
    dev, clock, port = sim
    port.write(b"$N=300\n$RUN\n")
    assert line(port) == OK and line(port) == OK
    port.write(b"\x18")
    assert port.read(len(ALARM_3 + WELCOME + ALARM_LOCK_MSG)) == ALARM_3 + WELCOME + ALARM_LOCK_MSG
    assert status(port)[1] == b"Alarm"
    port.write(b"$RUN\n")
    assert line(port) == b"error:9\r\n"
    port.write(b"$X\n")
    assert port.read(len(UNLOCKED)) == UNLOCKED
    port.write(b"$RUN\n")
    assert line(port) == OK


def test_sim_reset_at_rest_prints_only_the_welcome_message(sim):
    """G8: "The start up message always prints upon startup and after a reset"."""
    dev, clock, port = sim
    port.write(b"\x18")
    assert port.read(len(WELCOME) + 16) == WELCOME


def test_sim_version_lines(sim):
    """G2 form: [VER:version:string], [OPT:codes], ok."""
    dev, clock, port = sim
    port.write(b"$I\n")
    assert VERSION_RE.match(port.read(256))

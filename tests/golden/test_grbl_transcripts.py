"""Every transcript of the real GRBL 1.1h firmware (docs/golden/grbl-transcripts/) against the
simulator, the driver's parsers and, for the driver's own sessions, the driver itself.

The firmware was built here from gnea/grbl v1.1h and grbl-sim (docs/stepper-bench.md); CI needs
neither: it reads what the firmware printed. Nothing here is produced by the project's encoders.

(a) simulator: the host bytes of each transcript go to ``StepperBenchSim``; its answers must be
    the firmware's, byte for byte (tests/golden/grbl_replay.py says how time is aligned);
(b) simulator motion: its position against the firmware's own step log (grbl-sim's simulated
    time), within one step, over whole jogs: acceleration, cruise, deceleration, junctions,
    reversal, cancel and hold;
(c) driver parsers: every line the firmware sent is one the driver knows (its error and alarm
    tables hold every code the firmware used, every status report parses);
(d) driver sessions: the driver against a scripted peer playing its own recorded sessions on the
    firmware (instruments check, a two-rate procedure, Ctrl-C, a plain GRBL, an open after
    ALARM:3): it must write exactly what it wrote then and conclude what it concluded then.
"""

from __future__ import annotations

import copy
import re

import numpy as np
import pytest

from bench.clock import VirtualClock
from bench.sim.stepper_bench import StepperBenchSim, bench_eeprom
from drivers import grbl
from drivers.errors import NotConfigured
from drivers.stepper_bench import BenchSetup, StepperBench
from tests.golden.grbl_replay import (BENCH_EEPROM, _rest_steps_if_stopped_at, driver_calls, exchanges, play, start_units,
                                      stop_moment, transcript_port)
from tests.golden.grbl_transcript import TRANSCRIPTS, Transcript, all_transcripts, read_transcript

ALL = all_transcripts()
BY_NAME = {tr.name: tr for tr in ALL}
DRIVER_SESSIONS = [tr.name for tr in ALL if tr.header_value("driver")]
PROFILES = sorted(p.stem for p in TRANSCRIPTS.glob("*.steps"))
BENCH_SETUP = BenchSetup("X", 894.33, 3.5, 10.0)
"""The config of the driver's sessions (their ``lab.yaml`` note)."""


def test_the_transcripts_are_there_with_their_provenance():
    assert len(ALL) >= 16 and len(DRIVER_SESSIONS) == 5 and len(PROFILES) == 4
    for tr in ALL:
        for key in ("firmware", "simulator", "build", "run", "recorded", "eeprom"):
            assert tr.header_value(key), f"{tr.name}: no '# {key}:' line"
        assert "bdc2da9b5972c5972cdd4a4f045a575f09ff74cc" in tr.header_value("firmware")
        assert tr.events and any(e.direction == ">" for e in tr.events)


# ---- (a) the simulator ----------------------------------------------------------------------------
@pytest.mark.parametrize("name", sorted(BY_NAME))
def test_simulator_answers_as_the_firmware(name):
    assert play(BY_NAME[name]) == []


def test_the_comparison_notices_a_wrong_answer():
    """The same transcript with one byte of the firmware changed fails."""
    tr = copy.deepcopy(BY_NAME["errors"])
    for e in tr.events:
        if e.direction == "<" and e.data == b"error:16\r\n":
            e.data = b"error:3\r\n"
            break
    else:
        pytest.fail("the errors transcript lost its error:16")
    problems = play(tr)
    assert len(problems) == 1 and "error:3" in problems[0]


# ---- (b) the simulator's motion against the firmware's step log ------------------------------------
def _step_log(name: str) -> list[tuple[float, int]]:
    rows = []
    for line in (TRANSCRIPTS / f"{name}.steps").read_text(encoding="ascii").splitlines():
        if line.strip() and not line.startswith("#"):
            t, rest = line.split(None, 1)
            rows.append((float(t), int(rest.split(",")[0])))
    return rows


def _plateau(rows: list[tuple[float, int]]) -> tuple[int, float] | None:
    """(position, last time) of a hold in the step log: the axis at rest before its final position."""
    for k in range(len(rows) - 5):
        if rows[k][1] != rows[0][1] and rows[k][1] == rows[k + 4][1] != rows[-1][1]:
            j = k
            while rows[j + 1][1] == rows[k][1]:
                j += 1
            return rows[k][1], rows[j][0]
    return None


@pytest.mark.parametrize("name", PROFILES)
def test_simulator_motion_follows_the_firmware_step_log(name):
    """The firmware's X position (steps) against its own simulated time (s), every 5 ms while
    moving; the simulator given the same lines from the first step on, the cancel or hold at the
    moment that ends where the firmware came to rest (and a resume where it went on), must be
    within one step of it throughout; two after a resume, whose moment the 5-ms log leaves open
    (2.5 deg/s for up to 5 ms is 11 steps: the two show the profile, not the moment, agreeing)."""
    rows = _step_log(name)
    _, exs = exchanges(BY_NAME[name])
    clock = VirtualClock()
    sim = StepperBenchSim(clock, None, bench_eeprom(**BENCH_EEPROM))
    t0 = rows[0][0]
    stop = next((ex.host for ex in exs if ex.host in (b"\x85", b"!")), None)
    for line in (ex.host for ex in exs if ex.host.startswith((b"$J=", b"G"))):
        sim.receive(line)
    assert sim.motion.running
    hold = _plateau(rows)
    rest = hold[0] if hold else rows[-1][1]
    stopped, resumed = stop is None, hold is None
    worst = worst_after_resume = 0
    for t, steps in rows:
        t -= t0
        if not stopped and _rest_steps_if_stopped_at(sim.motion, t, 0) >= rest:
            clock.sleep_until(stop_moment(sim, clock.now(), t, rest))
            sim.receive(stop)  # the moment that ends on the firmware's step
            stopped = True
        if stopped and not resumed and t >= hold[1] - t0:
            clock.sleep_until(max(clock.now(), t))
            sim.receive(b"~")
            resumed = True
        clock.sleep_until(max(clock.now(), t))
        sim.pending_bytes(clock.now())
        d = abs(sim.motion.position_steps()[0] - steps)
        if hold is not None and resumed:
            worst_after_resume = max(worst_after_resume, d)
        else:
            worst = max(worst, d)
    assert worst <= 1 and worst_after_resume <= 2, f"{name}: the simulator was {worst} ({worst_after_resume}) steps from the firmware"
    assert stopped and resumed and sim.motion.position_steps()[0] == rows[-1][1]


# ---- (c) the driver's parsers ----------------------------------------------------------------------
_KNOWN = [re.compile(p) for p in (r"^ok$", r"^\[MSG:[^\]]*\]$", r"^\[GC:[^\]]*\]$", r"^\[HLP:[^\]]*\]$", r"^\[VER:[^\]]*\]$",
                                  r"^\[OPT:[^\]]*\]$", r"^\[(G5[4-9]|G28|G30|G92|TLO|PRB):[^\]]*\]$", r"^\$N[01]=.*$")]


@pytest.mark.parametrize("name", sorted(BY_NAME))
def test_driver_reads_every_line_the_firmware_sent(name):
    tr = BY_NAME[name]
    text = tr.firmware_bytes().decode("ascii")
    assert "\r\n" in text and not text.replace("\r\n", "").count("\n")  # GRBL ends every line with CR LF
    for line in (ln for ln in text.split("\r\n") if ln):
        if line.startswith("<"):
            st = grbl.parse_status(line)
            assert st.state in grbl.STATES and st.mpos is not None and st.feed is not None
        elif line.startswith("error:"):
            assert int(line[6:]) in grbl.ERRORS, line
        elif line.startswith("ALARM:"):
            assert int(line[6:]) in grbl.ALARMS, line
        elif line.startswith("Grbl "):
            assert grbl.welcome_version(line) == "1.1h", line
        elif line.startswith("$") and not line.startswith("$N"):
            assert grbl.parse_settings([line]), line
        else:
            assert any(p.match(line) for p in _KNOWN), f"{name}: the driver knows no line {line!r}"


def test_error_8_is_in_the_drivers_table_and_the_firmware_used_it():
    """The firmware answered error:8 (not idle) to $$ during a hold, $I and settings while jogging."""
    seen = {ln for tr in ALL for ln in tr.firmware_bytes().decode("ascii").split("\r\n") if ln.startswith("error:")}
    assert "error:8" in seen and "error:8" in grbl.MEANINGS
    assert {"error:2", "error:3", "error:9", "error:11", "error:16", "error:22"} <= seen


# ---- (d) the driver's own sessions -----------------------------------------------------------------
def _session(name: str) -> tuple[Transcript, list]:
    tr = BY_NAME[name]
    span = [float(x) for x in tr.header_value("driver").split()]
    _, exs = exchanges(tr, span[0], span[1] if len(span) > 1 else None)
    return tr, exs


def _driver(exs) -> tuple[StepperBench, object]:
    port = transcript_port(exs)
    return StepperBench(port, timeout_s=0.5, setup=BENCH_SETUP, boot_timeout_s=2.0), port


def _play_calls(drv: StepperBench, exs) -> list:
    results = []
    for call in driver_calls(exs, start_units(exs)):
        results.append((call[0], getattr(drv, call[0])(*call[1:])))
    return results


def test_driver_session_instruments_check_names_the_firmware():
    tr, exs = _session("driver-check-bench")
    drv, port = _driver(exs)
    drv.start()
    ident = drv.identify()
    assert ident["vendor"] == "GRBL" and ident["serial"] == "EC2-01" and "1.1h" in ident["firmware"]
    assert ident["settings"] == "$100=894.330 $110=210.000 $120=10.000"
    assert drv.status() == {"state": "Idle", "angle_deg": 0.0, "position_deg": 0.0, "rate_dps": 0.0}
    assert port.played() and not drv.notes


def test_driver_session_plain_grbl_is_reported_with_the_fix():
    tr, exs = _session("driver-check-plain")
    drv, port = _driver(exs)
    with pytest.raises(NotConfigured, match="GRBL, not configured as this bench") as err:
        drv.start()
    assert "$I=STEPPER_BENCH:" in err.value.fix and "$100=894.330" in err.value.fix
    assert "$110" not in err.value.fix  # a blank EEPROM's $110=500 allows 3.5 deg/s
    assert port.played()
    assert any("error:7" in n for n in drv.notes) is False  # the port was opened after the power-up


def test_driver_session_two_rates_then_stop():
    tr, exs = _session("driver-two-rates")
    drv, port = _driver(exs)
    drv.start()
    results = _play_calls(drv, exs)
    assert [r[0] for r in results if r[0] != "monitor"] == ["set_rate", "run", "set_rate", "stop"]
    rates = [r[1] for r in results if r[0] == "set_rate"]
    assert rates == [1.0, 0.2]
    monitors = [r[1] for r in results if r[0] == "monitor"]
    assert any(m["rate"] == pytest.approx(1.0) for m in monitors) and any(m["rate"] == pytest.approx(0.2) for m in monitors)
    assert port.played()
    assert drv.last_status.state == "Idle" and drv.last_status.feed == 0


def test_driver_session_ctrl_c_leaves_the_firmware_idle():
    tr, exs = _session("driver-ctrl-c")
    drv, port = _driver(exs)
    drv.start()
    results = _play_calls(drv, exs)
    told = results[-1]
    assert told[0] == "safe_state" and told[1].startswith("jog cancel (0x85): Idle, feed 0 at 2.800 deg")
    assert port.played()


def test_driver_session_open_after_alarm_unlocks_and_says_so():
    tr, exs = _session("driver-open-after-alarm")
    drv, port = _driver(exs)
    drv.start()
    assert drv.status()["state"] == "Idle"
    assert port.played()
    assert len(drv.notes) == 1 and "unlocked with $X" in drv.notes[0] and "unlocked with $X" in drv.identify()["notes"]


def test_a_driver_writing_other_bytes_fails_the_session():
    """The scripted peer is strict: the check session against a driver told another axis."""
    tr, exs = _session("driver-check-bench")
    port = transcript_port(exs)
    drv = StepperBench(port, timeout_s=0.5, setup=BenchSetup("Y", 894.33, 3.5), boot_timeout_s=2.0)
    with pytest.raises(NotConfigured, match=r"\$101=250.000"):
        drv.start()
    assert read_transcript(TRANSCRIPTS / "driver-check-bench.txt").header_value("driver")


def test_grbl_steps_at_the_rate_of_the_feed():
    """What the GRBL speed calibration rests on, from the firmware's own step log: cruising, the
    steps come at feed·$100/60 per second, with no offset (the thesis firmware had one, b of
    Eq. 3.1): 210 deg/min at 894.33 steps/deg is 3130.2 steps/s; 150, 2235.8; 120, 1788.7."""
    for name, feed in (("profile-jog-complete", 210.0), ("profile-feed-hold", 150.0), ("profile-jog-cancel", 120.0)):
        rows = _step_log(name)
        t = np.array([r[0] for r in rows])
        x = np.array([r[1] for r in rows], dtype=float)
        j = np.searchsorted(t, t + 0.1)
        ok = j < t.size
        windowed = (x[j[ok]] - x[ok]) / (t[j[ok]] - t[ok])  # steps/s over 0.1-s windows
        starts = np.flatnonzero(windowed >= 0.99 * windowed.max())  # windows inside a cruise
        runs = np.split(starts, np.flatnonzero(np.diff(starts) > 1) + 1)
        starts = max(runs, key=len)  # the longest cruise
        a = np.searchsorted(t, t[starts[0]] + 0.05)  # off the ramps' ends
        b = np.searchsorted(t, t[j[starts[-1]]] - 0.05)
        assert t[b] - t[a] >= 0.15, name
        measured = (x[b] - x[a]) / (t[b] - t[a])  # over the whole cruise: one step in 0.15 s is 0.2 %
        assert measured == pytest.approx(feed / 60 * 894.33, rel=3e-3), name

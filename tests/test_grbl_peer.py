"""A GRBL sender written by others, on the simulated bench: grbl-streamer (PyPI, Michael Franzl's
universal interface for the grbl firmware; installed with the test extras) connects to the
simulator on a pseudo-terminal, as to an Arduino, resets it, streams a short G-code program with
its own character-counting protocol and reads the status reports through its own parser.

The simulator runs on the wall clock here (grbl-streamer is threads and real time), so the program
is short: 1.3 s of motion. Skipped, saying why, where grbl_streamer cannot be imported.

Each wait is for the event it names, bounded by WAIT_S (generous: on a loaded machine the threads of
grbl-streamer, the pty server and pytest share a starved core). The test failed once in a full run at
load 5-9 ("saw no Idle at 0 deg within 20 s"); not reproduced since (12 runs beside four busy loops,
5 runs beside three GIL-holding threads, 400 virtual-time runs of the simulator alone with steps of up
to 3 s), so a failure now says what each side saw: the sender's last state reports, the simulator's
own state and angle, and any exception that ended a thread (the pty server's, or grbl-streamer's
reader, whose death would freeze its state).
"""

from __future__ import annotations

import threading
import time
import traceback

import pytest

from bench.clock import WallClock
from bench.sim.pty_server import close_endpoints, open_endpoint, serve
from bench.sim.stepper_bench import StepperBenchSim, bench_eeprom

grbl_streamer = pytest.importorskip("grbl_streamer", reason="grbl-streamer (PyPI) is not installed: "
                                    "'python3 dev.py test' installs the test extras; the peer sender is not run")

PROGRAM = ["G21 G91 (deg, incremental)", "G1 X0.5 F120", "G1 X0.5 F60", "G4 P0.2", "G1 X-1.0 F120", "M2"]
"""1 deg out at 2 then 1 deg/s, a 0.2-s dwell, back at 2 deg/s, program end."""
WAIT_S = 60.0


class Events:
    def __init__(self):
        self.seen: list[tuple] = []
        self.cond = threading.Condition()
        self.thread_errors: list[str] = []
        self.context = lambda: ""  # what the other side (the simulator) says, for a failure message

    def __call__(self, event, *data):
        with self.cond:
            self.seen.append((event, *data))
            self.cond.notify_all()

    def wait_for(self, predicate, what: str, timeout_s: float = WAIT_S) -> None:
        with self.cond:
            if not self.cond.wait_for(lambda: predicate(self.seen) or self.thread_errors, timeout=timeout_s):
                reports = [e[1:3] for e in self.seen if e[0] == "on_stateupdate"][-8:]
                pytest.fail(f"grbl-streamer saw no {what} within {timeout_s:g} s; it saw {[e[0] for e in self.seen][-30:]}; "
                            f"its last state reports {reports}; {self.context()}")
            assert not self.thread_errors, "a thread ended with an exception:\n" + "\n".join(self.thread_errors)

    def thread_died(self, args) -> None:
        """threading.excepthook during the test: a thread that dies (the pty server, grbl-streamer's
        reader) would otherwise only freeze what the other side sees."""
        with self.cond:
            self.thread_errors.append(f"{args.thread.name if args.thread else '?'}: "
                                      + "".join(traceback.format_exception(args.exc_type, args.exc_value, args.exc_traceback)))
            self.cond.notify_all()


def test_grbl_streamer_streams_a_program_and_reads_status(monkeypatch):
    clock = WallClock()
    sim = StepperBenchSim(clock, None, bench_eeprom(894.33, 210.0, 10.0, build_info="STEPPER_BENCH:PEER"))
    sim.take_output(clock.now())  # its power-up was long ago: the sender meets a running board
    ep = open_endpoint("stepper_bench", sim)
    stop = threading.Event()
    server = threading.Thread(target=serve, args=([ep], clock, stop.is_set), daemon=True)
    server.start()
    events = Events()
    events.context = lambda: (f"the simulator: state {sim.machine_state()}, angle {sim.angle_deg():.6f} deg; "
                              f"pty server thread {'alive' if server.is_alive() else 'ENDED'}")
    monkeypatch.setattr(threading, "excepthook", events.thread_died)
    grbl = grbl_streamer.GrblStreamer(events, name="peer")
    grbl.setup_logging()
    try:
        grbl.cnect(ep.path, 115200)  # opens the pty, soft-resets
        events.wait_for(lambda s: any(e[0] == "on_boot" for e in s), "welcome message (on_boot)")
        events.wait_for(lambda s: any(e[0] == "on_gcode_parser_stateupdate" for e in s), "its $G after the boot")
        grbl.poll_start()
        start = len(events.seen)
        grbl.write("\n".join(PROGRAM))
        grbl.job_run()

        def states(seen):
            return [e for e in seen[start:] if e[0] == "on_stateupdate"]

        events.wait_for(lambda s: any(e[1] == "Run" for e in states(s)), "Run in a status report")
        events.wait_for(lambda s: states(s)[-1][1] == "Idle" and abs(states(s)[-1][2][0]) < 1e-9, "Idle at 0 deg")
        events.wait_for(lambda s: any(e[0] == "on_job_completed" for e in s[start:]), "the end of the job")
    finally:
        grbl.poll_stop()
        grbl.disconnect()
        stop.set()
        server.join(timeout=5)
        close_endpoints([ep])
    assert not events.thread_errors, events.thread_errors
    errors = [e for e in events.seen if e[0] in ("on_error", "on_alarm")]
    assert not errors, errors
    states = [e for e in events.seen[start:] if e[0] == "on_stateupdate"]
    modes = {e[1] for e in states}
    assert {"Run", "Idle"} <= modes, modes  # it parsed our reports while the program ran
    peak = max(e[2][0] for e in states)
    assert 0.3 < peak <= 1.0 + 1e-9  # its parser read the positions on the way out (1 deg at most) ...
    assert grbl.cmode == "Idle" and grbl.cmpos[0] == pytest.approx(0.0, abs=1e-9)  # ... and back where it started
    assert sim.angle_deg() == pytest.approx(0.0, abs=1e-9)

"""An independent reference for the sensor board's samples of a dry-run: the dry-run again.

A replay answers the board's data requests with frames re-encoded from the recorded rows, so the
board stream of a replay equals the recorded one by construction, whatever was done to it after
the run (a temperature raised by 10 degC replays as a match). Everything else a replay compares is
re-produced from what the instruments answered (polled readings from the recorded reply bytes,
checks from the streams, commands from the drivers). For a dry-run recorded on the virtual clock
the simulators are deterministic: the stored procedure, the recorded parameters and operator
answers and the recorded config give the same samples bit for bit. :func:`resimulate` runs that
dry-run again, recorded into the replay's private directory, and the comparison checks the
recorded board streams against it (docs/replay.md, "What is compared").

It is skipped, with the reason, for hardware and wall-clock recordings (nothing to re-simulate),
recordings with injected faults (a fault changes what the simulators send), recordings without a
board stream (nothing the replay does not re-produce itself), and when the simulators cannot be
built from the recorded config (a sensor model that is neither in the run file nor in the
project's ``configs/``).
"""

from __future__ import annotations

from pathlib import Path

from bench import __version__
from bench.config import LabConfig
from bench.errors import InputError
from bench.procedure import Procedure
from bench.record import RunRecorder, layout
from bench.replay.recording import Recording

def board_streams(rec: Recording, config: LabConfig) -> list[str]:
    """Keys of the recorded streams the replay re-encodes from the recording: the data streams of
    the instruments whose kind streams (a board; their monitor streams are polled readings,
    re-produced from replies)."""
    boards = {n for n, i in config.instruments.items() if i.kind.streams}
    return [s.key for s in rec.summary.streams if s.key in boards]


def why_not(rec: Recording, keys: list[str]) -> str:
    """Why the board's samples of ``rec`` cannot be re-simulated (``""``: they can)."""
    if not keys:
        return ""
    if rec.mode != layout.MODE_SIM or rec.clock != "virtual":
        return "recorded on hardware or on the wall clock: there is no independent reference for them"
    if rec.faults_injected:
        return "faults were injected into the recorded run"
    return ""


def resimulate(procedure: Procedure, config: LabConfig, rec: Recording, out_dir: Path) -> Path:
    """Dry-run ``procedure`` (the stored one, with the recorded parameters) on the simulators of
    ``config`` on a virtual clock, the operator answering as recorded; the run file, in
    ``out_dir``. :class:`InputError` when the simulators cannot be built."""
    from bench.lab import open_lab
    from bench.replay.run import QuietProgress, ReplayOperator
    from bench.runner import Runner

    recorder = RunRecorder.create(out_dir, procedure_name=procedure.name, procedure_text=procedure.text,
                                  procedure_path=rec.procedure_path, config_text=config.text,
                                  config_path=str(rec.summary.attrs.get(layout.ATTR_CONFIG_PATH, "")), mode=layout.MODE_SIM,
                                  software_version=__version__, flush_interval_s=config.flush_interval_s)
    try:
        lab = open_lab(config, procedure.instruments, sim=True, realtime=False)
    except BaseException as exc:
        recorder.close(layout.STATUS_ABORTED, f"instruments could not be opened: {exc}")
        if isinstance(exc, (InputError, ValueError, OSError)):
            raise InputError(str(exc)) from None
        raise
    try:
        Runner(procedure, lab, recorder, QuietProgress(), ReplayOperator(rec.answers)).run()
    finally:
        lab.close()
        if not recorder.closed:
            recorder.close(layout.STATUS_FAILED, "re-simulation ended without closing its file")
    return recorder.path

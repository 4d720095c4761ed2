"""The real GRBL 1.1 firmware on a pseudo-terminal, for machine-local checks (never needed by CI).

GRBL is open source and grbl-sim compiles it for a PC with its serial port on stdin/stdout
(docs/stepper-bench.md, "Proven against the real firmware", says how it was built and from which
commits). Where such a binary exists, name it in ``BENCH_GRBL_SIM`` (the path of ``grbl_sim.exe``);
without it everything here skips with the reason printed. Nothing here builds the firmware.

:class:`GrblFirmware` starts the binary on one pseudo-terminal and relays it to a second one whose
path a driver opens like any serial port, recording every byte each way with its time. The
recording is what ``docs/golden/grbl-transcripts/`` holds (:mod:`tests.golden.grbl_transcript`
reads and writes that format).

    BENCH_GRBL_SIM=/path/to/grbl_sim.exe .venv/bin/python -m tests.grbl_firmware serve --eeprom bench
        # prints the pty path; point a config's stepper_bench port at it; Ctrl-C writes the transcript
    BENCH_GRBL_SIM=... .venv/bin/python -m tests.grbl_firmware record docs/golden/grbl-transcripts
        # re-records the scripted raw sessions (tests/golden/grbl_sessions.py)
"""

from __future__ import annotations

import argparse
import os
import pty
import select
import shutil
import signal
import subprocess
import tempfile
import threading
import time
import tty
from pathlib import Path

ENV = "BENCH_GRBL_SIM"
"""Environment variable naming the grbl-sim binary (``grbl_sim.exe``) built from GRBL 1.1h."""

EXIT_BYTE = b"\x06"
"""grbl-sim's Ctrl-F: shut down cleanly when idle (writes its EEPROM file)."""

EEPROM_FILE = "EEPROM.DAT"
"""Where grbl-sim keeps the firmware's EEPROM (4 KiB), in its working directory."""


def firmware_binary() -> Path | None:
    """The grbl-sim binary named by :data:`ENV`, or None when there is none."""
    path = os.environ.get(ENV, "")
    return Path(path) if path and Path(path).is_file() and os.access(path, os.X_OK) else None


def skip_reason() -> str:
    """Why the firmware cannot run here."""
    path = os.environ.get(ENV, "")
    if not path:
        return f"{ENV} is not set: no GRBL 1.1 firmware built with grbl-sim on this machine (docs/stepper-bench.md)"
    return f"{ENV}={path} is not an executable file"


class GrblFirmware:
    """GRBL 1.1 (grbl-sim) behind a pseudo-terminal at :attr:`port`, every byte recorded.

    ``eeprom``: an EEPROM image to start from (None: blank, as a freshly flashed board).
    ``step_file`` / ``report_step_s``: grbl-sim's step log (its own simulated time, s, and the
    axis positions in steps every ``report_step_s`` of simulated time while a block executes)."""

    def __init__(self, binary: Path, *, eeprom: Path | None = None, step_file: Path | None = None,
                 report_step_s: float | None = None, nice: int = 10):
        self.binary = Path(binary)
        self.workdir = Path(tempfile.mkdtemp(prefix="grbl-fw-"))
        if eeprom is not None:
            shutil.copy(eeprom, self.workdir / EEPROM_FILE)
        self.events: list[tuple[float, str, bytes]] = []
        """(wall s since start, ">" host to firmware | "<" firmware to host, bytes)."""
        self._lock = threading.Lock()
        self._fw_master, fw_slave = pty.openpty()
        tty.setraw(fw_slave)
        self._host_master, self._host_slave = pty.openpty()
        tty.setraw(self._host_slave)
        self.port = os.ttyname(self._host_slave)
        args = [str(self.binary), "-n", "-b", "/dev/null", "-s", str(step_file) if step_file else "/dev/null"]
        if report_step_s:
            args += ["-r", f"{report_step_s:g}"]
        self.t0 = time.monotonic()
        self.proc = subprocess.Popen(["nice", "-n", str(nice), *args], stdin=fw_slave, stdout=fw_slave,
                                     stderr=subprocess.DEVNULL, cwd=self.workdir, close_fds=True,
                                     start_new_session=True)
        os.close(fw_slave)
        self._stop = False
        self._thread = threading.Thread(target=self._relay, name="grbl-relay", daemon=True)
        self._thread.start()

    def _relay(self) -> None:
        fds = [self._fw_master, self._host_master]
        while not self._stop:
            try:
                ready, _, _ = select.select(fds, [], [], 0.05)
            except (OSError, ValueError):
                return
            for fd in ready:
                try:
                    data = os.read(fd, 4096)
                except OSError:
                    data = b""
                if not data:
                    if fd == self._fw_master:
                        return
                    continue
                t = time.monotonic() - self.t0
                if fd == self._fw_master:
                    self._record(t, "<", data)
                    os.write(self._host_master, data)
                else:
                    self._record(t, ">", data)
                    os.write(self._fw_master, data)

    def _record(self, t: float, direction: str, data: bytes) -> None:
        with self._lock:
            self.events.append((t, direction, data))

    def received(self) -> bytes:
        """Everything the firmware has sent so far."""
        with self._lock:
            return b"".join(d for _, k, d in self.events if k == "<")

    def wait_for(self, marker: bytes, timeout_s: float, start: int = 0) -> bool:
        """Wait until ``marker`` appears in what the firmware sent (from byte ``start``)."""
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if marker in self.received()[start:]:
                return True
            time.sleep(0.02)
        return False

    def stop(self) -> None:
        """Ask grbl-sim to exit (Ctrl-F, not recorded: it is no GRBL command), then end it."""
        try:
            os.write(self._fw_master, EXIT_BYTE)
            self.proc.wait(timeout=5)
        except (OSError, subprocess.TimeoutExpired):
            try:
                os.killpg(self.proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            self.proc.wait(timeout=5)
        self._stop = True
        self._thread.join(timeout=2)
        for fd in (self._fw_master, self._host_master, self._host_slave):
            try:
                os.close(fd)
            except OSError:
                pass

    def eeprom(self) -> bytes:
        """The firmware's EEPROM file as grbl-sim left it (after :meth:`stop`)."""
        return (self.workdir / EEPROM_FILE).read_bytes()

    def cleanup(self) -> None:
        shutil.rmtree(self.workdir, ignore_errors=True)

    def __enter__(self) -> "GrblFirmware":
        return self

    def __exit__(self, *exc) -> None:
        self.stop()
        self.cleanup()


def _serve(args) -> int:
    from tests.golden.grbl_transcript import write_transcript

    binary = firmware_binary()
    if binary is None:
        print(skip_reason())
        return 2
    eeprom = None if args.eeprom == "blank" else Path(args.eeprom)
    stopping = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stopping.set())
    fw = GrblFirmware(binary, eeprom=eeprom)
    if args.port_file:
        Path(args.port_file).write_text(fw.port + "\n")
    print(f"GRBL firmware on {fw.port}  (pid {os.getpid()}; SIGINT or SIGTERM stops it and writes {args.out})", flush=True)
    while fw.proc.poll() is None and not stopping.is_set():
        time.sleep(0.2)
    fw.stop()
    write_transcript(Path(args.out), fw.events, title=args.title, eeprom=args.eeprom_name or args.eeprom, notes=args.note)
    if args.save_eeprom:
        Path(args.save_eeprom).write_bytes(fw.eeprom())
    fw.cleanup()
    print(f"wrote {args.out}")
    return 0


def _record(args) -> int:
    from tests.golden import grbl_sessions

    binary = firmware_binary()
    if binary is None:
        print(skip_reason())
        return 2
    grbl_sessions.record_all(binary, Path(args.outdir), only=args.only)
    grbl_sessions.record_profiles(binary, Path(args.outdir), only=args.only)
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m tests.grbl_firmware", description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("serve", help="run the firmware on a pty until Ctrl-C, then write the transcript")
    s.add_argument("--eeprom", default="blank", help="EEPROM image to start from, or 'blank'")
    s.add_argument("--eeprom-name", default="", help="how the transcript names that EEPROM")
    s.add_argument("--out", default="grbl-session.txt")
    s.add_argument("--title", default="a session of the driver against the firmware")
    s.add_argument("--note", action="append", default=[])
    s.add_argument("--save-eeprom", default="", help="write the EEPROM image here on exit")
    s.add_argument("--port-file", default="", help="write the pty path here once it is up")
    r = sub.add_parser("record", help="record the scripted raw sessions")
    r.add_argument("outdir")
    r.add_argument("--only", action="append", default=[])
    args = p.parse_args(argv)
    return _serve(args) if args.cmd == "serve" else _record(args)


if __name__ == "__main__":
    raise SystemExit(main())

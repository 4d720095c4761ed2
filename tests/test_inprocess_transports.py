"""The dry-run's in-process transports put the same bytes on the wire as the socket path.

The same short procedure runs twice on the simulated lab: once with ``BENCH_DRYRUN_TRANSPORT=socket``
(a pymodbus Modbus TCP server in its own thread, pymodbus's serial client for RTU, the rate table on
a python-can virtual bus with notifier threads) and once in-process (the default: Modbus ADUs on an
in-process stream, CAN frames on a synchronous bus, answered in the caller's thread). Every recorded
command and reply (instrument, direction, name, raw bytes, run time) and every recorded stream must
be identical; replaying either run file on either path must match.
"""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from bench.cli import main
from bench.config import load_config
from bench.lab import DRYRUN_TRANSPORT_ENV, open_lab
from bench.record import read_run_summary
from bench.replay import replay
from bench.sim.factory import build_devices
from bench.clock import VirtualClock
from drivers.watlow_f4 import WatlowF4
from tests.conftest import SIM_CONFIG

PROCEDURE = """schema: bench-procedure/1
name: transports
instruments: [tvac, rate_table, thermocouples]
steps:
  - set_temperature: {instrument: tvac, set_point: 30 degC, ramp: 2 degC/min}
  - table_rate: {instrument: rate_table, rate: 2 deg/s}
  - wait: 20 s
  - table_move: {instrument: rate_table, angle: 90 deg, rate: 10 deg/s}
  - table_tilt: {instrument: rate_table, angle: 10 deg}
  - wait: 10 s
  - table_rate: {instrument: rate_table, rate: 0 deg/s}
  - set_temperature: {instrument: tvac, set_point: 20 degC}
"""

TRAFFIC = ("command", "reply")


def _config(tmp_path: Path, rtu: bool) -> Path:
    text = SIM_CONFIG.read_text().replace("sensor_model: sensors/", f"sensor_model: {SIM_CONFIG.parent}/sensors/")
    if rtu:
        text = text.replace("      # transport: rtu ", "      transport: rtu  # ", 1)
        assert "      transport: rtu  #" in text
    path = tmp_path / "cfg.yaml"
    path.write_text(text)
    return path


def _run(tmp_path: Path, monkeypatch, transport: str, rtu: bool = False) -> Path:
    monkeypatch.setenv(DRYRUN_TRANSPORT_ENV, transport)
    proc = tmp_path / "transports.yaml"
    proc.write_text(PROCEDURE)
    runs = tmp_path / f"runs-{transport}"
    assert main(["run", str(proc), "--config", str(_config(tmp_path, rtu)), "--runs-dir", str(runs)]) == 0
    (path,) = sorted(runs.glob("*.h5"))
    return path


def _traffic(path: Path) -> list[tuple]:
    return [(e.source, e.kind, e.message, e.data, e.t_s) for e in read_run_summary(path).events if e.kind in TRAFFIC]


def _streams(path: Path) -> dict[str, np.ndarray]:
    out = {}
    with h5py.File(path, "r") as f:
        f["streams"].visititems(lambda name, obj: out.__setitem__(name, obj[()]) if isinstance(obj, h5py.Dataset) else None)
    return out


@pytest.mark.parametrize("rtu", [False, True], ids=["modbus-tcp", "modbus-rtu"])
def test_socket_and_inprocess_paths_record_the_same_bytes_and_streams(tmp_path: Path, monkeypatch, rtu: bool):
    socket_run = _run(tmp_path, monkeypatch, "socket", rtu)
    inproc_run = _run(tmp_path, monkeypatch, "inprocess", rtu)
    a, b = _traffic(socket_run), _traffic(inproc_run)
    sources = {s for s, *_ in a}
    assert {"tvac", "rate_table", "thermocouples"} <= sources  # every link carried traffic
    assert any(k == "reply" and n.startswith("TPDO") for s, k, n, *_ in a)  # the rate table's PDOs
    assert len(a) == len(b)
    for i, (x, y) in enumerate(zip(a, b)):
        assert x == y, f"exchange {i} differs: socket {x} vs in-process {y}"
    sa, sb = _streams(socket_run), _streams(inproc_run)
    assert sa.keys() == sb.keys() and any(k.startswith("tvac") for k in sa)
    for key in sa:
        np.testing.assert_array_equal(sa[key], sb[key], err_msg=key)


def test_each_path_replays_the_other_paths_recording(tmp_path: Path, monkeypatch):
    socket_run = _run(tmp_path, monkeypatch, "socket")
    inproc_run = _run(tmp_path, monkeypatch, "inprocess")
    for source, transport in ((socket_run, "inprocess"), (inproc_run, "socket")):
        monkeypatch.setenv(DRYRUN_TRANSPORT_ENV, transport)
        result = replay(source, runs_dir=tmp_path / f"replays-{transport}")
        assert result.ok, (transport, result)


def test_the_inprocess_lab_uses_no_sockets_or_notifier_threads(monkeypatch):
    monkeypatch.delenv(DRYRUN_TRANSPORT_ENV, raising=False)
    lab = open_lab(load_config(SIM_CONFIG), ["tvac", "rate_table"], sim=True, realtime=False)
    try:
        assert lab.ports["tvac"].startswith("modbus-tcp+stream://sim://")
        assert lab.ports["rate_table"].startswith("can://sync/")
        assert lab.instruments["rate_table"].network.notifier is None
        assert lab.sims["rate_table"].device.network.notifier is None
        assert lab.instruments["tvac"].controller.read_air_temp_c() == pytest.approx(20.0, abs=1.0)
    finally:
        lab.close()


def test_an_unknown_transport_is_refused_naming_the_variable(tmp_path: Path, monkeypatch, capsys):
    monkeypatch.setenv(DRYRUN_TRANSPORT_ENV, "pigeon")
    proc = tmp_path / "p.yaml"
    proc.write_text(PROCEDURE)
    assert main(["run", str(proc), "--config", str(SIM_CONFIG), "--runs-dir", str(tmp_path / "runs")]) == 2
    err = capsys.readouterr().err
    assert DRYRUN_TRANSPORT_ENV in err and "pigeon" in err and "Traceback" not in err


def test_inprocess_controller_drops_and_refuses_connections_while_disconnected():
    clock = VirtualClock()
    sim = build_devices(load_config(SIM_CONFIG), clock, ["tvac"])["tvac"]
    from bench.sim import registry

    registry.register("tvac-disc", sim.serial[""])
    try:
        drv = WatlowF4.open("modbus-tcp+stream://sim://tvac-disc", timeout_s=0.5)
        sim.device.inject("disconnect")
        from drivers.errors import InstrumentError

        with pytest.raises(InstrumentError, match="cannot connect"):
            drv.read_air_temp_c()  # the open connection is lost, reconnecting is refused
        sim.device.clear_faults()
        assert drv.read_air_temp_c() == pytest.approx(20.0, abs=1.0)
        drv.close()
    finally:
        registry.unregister("tvac-disc")
        sim.close()


def test_sync_bus_delivers_in_the_senders_thread_before_send_returns():
    import threading

    import can

    from drivers.can_transport import SyncBus

    a, b, c = SyncBus("sync-test"), SyncBus("sync-test"), SyncBus("sync-test")
    try:
        got = []
        b.add_listener(lambda m: got.append((threading.get_ident(), m.arbitration_id, bytes(m.data))))
        a.send(can.Message(arbitration_id=0x601, data=b"\x40\x00\x10\x00", is_extended_id=False))
        assert got == [(threading.get_ident(), 0x601, b"\x40\x00\x10\x00")]  # already there, from this thread
        kept = c.recv(0)  # no listener: kept for recv()
        assert kept is not None and kept.arbitration_id == 0x601 and kept.is_rx
        assert a.recv(0) is None  # a bus does not hear itself
    finally:
        for bus in (a, b, c):
            bus.shutdown()

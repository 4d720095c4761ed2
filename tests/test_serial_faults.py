"""Serial-link faults injected between simulator and driver reach the drivers as on hardware."""

from __future__ import annotations

import numpy as np
import pytest

from bench.config import load_config
from bench.errors import InstrumentError, InstrumentTimeout
from bench.lab import open_lab
from tests.conftest import SIM_CONFIG


@pytest.fixture
def lab():
    config = load_config(SIM_CONFIG)
    lab = open_lab(config, ["acs_board", "stepper_bench", "thermocouples"], sim=True, realtime=False)
    yield lab
    lab.close()


def stream_for(lab, seconds: float):
    board = lab.instruments["acs_board"]
    batches = []
    t_end = lab.clock.now() + seconds
    while lab.clock.now() < t_end:
        lab.clock.sleep(0.5)
        batches.append(board.poll())
    return batches


def test_corrupted_bytes_become_crc_errors_and_the_stream_resynchronises(lab):
    board = lab.instruments["acs_board"]
    link = lab.sims["acs_board"].serial[""]
    board.sensor_power(True)
    board.start_stream()
    clean = stream_for(lab, 5.0)
    assert sum(b.crc_errors for b in clean) == 0
    link.inject("corrupt", p=2e-3)
    bad = stream_for(lab, 20.0)
    link.clear()
    after = stream_for(lab, 5.0)
    n_bad = sum(b.counter.size for b in bad)
    assert sum(b.crc_errors + b.dropped_frames for b in bad) > 0
    assert 0.5 * 2000 < n_bad < 2000  # most frames of 20 s at 100 Hz survive a 0.2 % byte error rate
    counters = np.concatenate([b.counter for b in after]).astype(int)
    assert counters.size >= 480 and np.all(np.diff(counters) % 65536 == 1)


def test_garbage_burst_is_skipped_by_the_decoder(lab):
    board = lab.instruments["acs_board"]
    link = lab.sims["acs_board"].serial[""]
    board.sensor_power(True)
    board.start_stream()
    stream_for(lab, 1.0)
    link.inject("garbage", count=500)
    batches = stream_for(lab, 3.0)
    assert sum(b.garbage_bytes for b in batches) >= 400
    counters = np.concatenate([b.counter for b in batches]).astype(int)
    assert counters.size >= 290  # no frame lost to the garbage itself


def test_disconnect_raises_instrument_error_and_replug_recovers(lab):
    bench = lab.instruments["stepper_bench"]
    link = lab.sims["stepper_bench"].serial[""]
    assert bench.status()["state"] == "Idle"
    link.inject("disconnect")
    with pytest.raises(InstrumentError, match="disconnected"):
        bench.status()
    link.clear("disconnect")
    assert bench.status()["state"] == "Idle"


def test_stall_gives_a_timeout_within_the_port_timeout(lab):
    logger = lab.instruments["thermocouples"]
    link = lab.sims["thermocouples"].serial[""]
    link.inject("stall", duration_s=30.0)
    t0 = lab.clock.now()
    with pytest.raises(InstrumentTimeout):
        logger.identify()
    assert lab.clock.now() - t0 <= 1.0 + 1e-6  # the logger's 1 s timeout (configs/sim.yaml)
    lab.clock.sleep(30.0)
    logger.port.reset_input_buffer()
    assert logger.identify()["serial"] == "SIM-0003"


def test_unknown_fault_is_refused(lab):
    with pytest.raises(ValueError, match="unknown serial fault"):
        lab.sims["acs_board"].serial[""].inject("lightning")

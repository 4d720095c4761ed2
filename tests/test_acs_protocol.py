"""ACS frame codec: round trips, resynchronisation, error counting (property-based)."""

from __future__ import annotations

import binascii

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from drivers import acs_protocol as proto
from drivers.crc import crc16_xmodem, crc16_xmodem_rows

I16 = st.integers(-32768, 32767)
SYNC = b"\xa5\x5a"  # the sync word every frame starts with (docs/acs-board-protocol.md)


def frame_bytes(batch: proto.DecodedBatch) -> int:
    """Bytes of the input that ``batch``'s good frames (data frames and replies) took."""
    return proto.DATA_FRAME_LEN * batch.counter.size + sum(proto.OVERHEAD + len(p) for _, p in batch.replies)


@st.composite
def raw_frames(draw, min_size=1, max_size=40):
    n = draw(st.integers(min_size, max_size))
    c0 = draw(st.integers(0, 65535))
    t0 = draw(st.integers(0, 2**32 - 1))
    vec = lambda: draw(arrays(np.int16, (n, 3), elements=I16))  # noqa: E731
    return {
        "counter": ((c0 + np.arange(n)) % 65536).astype(np.uint16),
        "board_time_us": ((t0 + 10_000 * np.arange(n, dtype=np.int64)) % 2**32).astype(np.uint32),
        "gyro_raw": vec(), "accel_raw": vec(), "mag_raw": vec(), "temp_raw": vec(),
        "status": draw(arrays(np.uint16, (n,), elements=st.integers(0, 65535))),
    }


def encode(f) -> bytes:
    return proto.encode_data_frames(**f)


def test_crc_check_value():
    assert crc16_xmodem(b"123456789") == 0x31C3
    assert crc16_xmodem_rows(np.frombuffer(b"123456789", np.uint8)[None])[0] == 0x31C3


@given(arrays(np.uint8, st.tuples(st.integers(1, 20), st.integers(1, 41))))
def test_batch_crc_equals_crc_hqx(rows):
    got = crc16_xmodem_rows(rows)
    assert [int(x) for x in got] == [binascii.crc_hqx(r.tobytes(), 0) for r in rows]


def test_layout_is_consistent():
    assert proto.DATA_DTYPE.itemsize == proto.DATA_FRAME_LEN == 38
    fields = proto.DESCRIPTION.fields
    ends = [f.at + np.dtype(f.dtype).itemsize * f.count for f in fields]
    assert fields[0].at == proto.HEADER_LEN and ends[-1] == proto.CRC_OFFSET
    assert all(e == f.at for e, f in zip(ends[:-1], fields[1:]))  # contiguous, no gaps


@settings(max_examples=200)
@given(raw_frames())
def test_data_frames_round_trip(f):
    b = proto.FrameDecoder().feed(encode(f))
    assert b.frames_ok == len(f["counter"]) and b.crc_errors == 0 and b.garbage_bytes == 0
    assert np.array_equal(b.counter, f["counter"])
    assert np.array_equal(b.status, f["status"])
    assert np.allclose(b.gyro_dps, f["gyro_raw"] * proto.GYRO_DPS_PER_LSB)
    assert np.allclose(b.mag_ut, f["mag_raw"] * proto.MAG_UT_PER_LSB)
    assert np.allclose(b.temp_degc, f["temp_raw"] * 0.01)
    # board time unwrapped across the 2**32 µs wrap: strictly increasing by 10 ms
    assert np.allclose(np.diff(b.board_time_s), 0.01)


@settings(max_examples=100)
@given(arrays(np.float64, (5, 3), elements=st.floats(-260, 260)), arrays(np.float64, (5, 3), elements=st.floats(-1.99, 1.99)))
def test_physical_values_within_half_lsb_or_saturated(gyro, accel):
    g, a, m, t, sat = proto.physical_to_raw(gyro, accel, np.zeros((5, 3)), np.full((5, 3), 21.37))
    frames = proto.encode_data_frames(np.arange(5), np.arange(5), g, a, m, t, np.zeros(5))
    b = proto.FrameDecoder().feed(frames)
    in_range = np.abs(gyro) < 249.99
    assert np.all(np.abs(b.gyro_dps - gyro)[in_range] <= proto.GYRO_DPS_PER_LSB / 2 + 1e-12)
    assert np.all(np.abs(b.accel_g - accel) <= proto.ACCEL_G_PER_LSB / 2 + 1e-12)
    counts = np.rint(gyro / proto.GYRO_DPS_PER_LSB)
    assert np.array_equal(sat, np.any((counts > 32767) | (counts < -32768), axis=1))
    assert np.allclose(b.temp_degc, 21.37)


@settings(max_examples=200)
@given(raw_frames(max_size=30), st.lists(st.integers(0, 1200), max_size=12))
def test_any_chunking_decodes_the_same(f, cuts):
    data = encode(f)
    whole = proto.FrameDecoder().feed(data)
    dec = proto.FrameDecoder()
    bounds = sorted({0, len(data), *[c % (len(data) + 1) for c in cuts]})
    parts = [dec.feed(data[a:b]) for a, b in zip(bounds[:-1], bounds[1:])]
    assert np.array_equal(np.concatenate([p.counter for p in parts]), whole.counter)
    assert np.array_equal(np.concatenate([p.gyro_dps for p in parts]), whole.gyro_dps)
    assert np.array_equal(np.concatenate([p.board_time_s for p in parts]), whole.board_time_s)
    assert dec.garbage_bytes == 0 and dec.crc_errors == 0 and dec.frames_ok == len(f["counter"])


no_sync = st.binary(min_size=1, max_size=60).filter(lambda b: b"\xa5" not in b)


@settings(max_examples=200)
@given(raw_frames(min_size=2, max_size=20), st.data())
def test_garbage_between_frames_is_skipped_and_counted(f, data):
    frames = encode(f)
    n = len(f["counter"])
    out, expected_garbage = b"", 0
    for i in range(n):
        if data.draw(st.booleans()):
            g = data.draw(no_sync)
            out += g
            expected_garbage += len(g)
        out += frames[i * 38:(i + 1) * 38]
    b = proto.FrameDecoder().feed(out)
    assert b.frames_ok == n and b.garbage_bytes == expected_garbage and b.crc_errors == 0
    assert np.array_equal(b.counter, f["counter"])


def test_garbage_containing_sync_words_is_resynchronised():
    f = encode({"counter": np.arange(3), "board_time_us": np.arange(3), "gyro_raw": np.zeros((3, 3)), "accel_raw": np.zeros((3, 3)),
                "mag_raw": np.zeros((3, 3)), "temp_raw": np.zeros((3, 3)), "status": np.zeros(3)})
    junk = b"\xa5\x5a\x01\x20" + bytes(10)  # a plausible header whose frame would swallow the next one
    b = proto.FrameDecoder().feed(f[:38] + junk + f[38:])
    assert list(b.counter) == [0, 1, 2]
    assert b.crc_errors == 1 and b.garbage_bytes == len(junk)


@settings(max_examples=200)
@given(raw_frames(min_size=3, max_size=10), st.data())
def test_single_bit_flip_is_detected(f, data):
    frames = bytearray(encode(f))
    n = len(f["counter"])
    k = data.draw(st.integers(0, n - 1))
    bit = data.draw(st.integers(2 * 8, 38 * 8 - 1))  # anywhere after the sync word
    frames[k * 38 + bit // 8] ^= 1 << (bit % 8)
    dec = proto.FrameDecoder()
    b = dec.feed(bytes(frames))
    assert b.frames_ok == n - 1
    assert k not in [(int(c) - int(f["counter"][0])) % 65536 for c in b.counter]
    expect_drop = 1 if 0 < k < n - 1 else 0  # a lost first or last frame leaves no gap to see
    assert b.dropped_frames == expect_drop
    assert b.garbage_bytes + dec.pending_bytes == 38  # a trailing A5 is held as a possible sync start
    if bit >= 32:  # payload or CRC: the header is intact, so the CRC check catches it
        assert b.crc_errors >= 1
    else:  # type or length: the header may no longer be plausible; then the bytes are garbage
        assert b.crc_errors <= 1


def test_counter_gaps_counted_across_wrap_and_feeds():
    def frames(counters):
        n = len(counters)
        z = np.zeros((n, 3))
        return proto.encode_data_frames(np.array(counters), np.arange(n), z, z, z, z, np.zeros(n))

    dec = proto.FrameDecoder()
    assert dec.feed(frames([65533, 65534, 1, 2])).dropped_frames == 2  # 65535 and 0 lost
    assert dec.feed(frames([5])).dropped_frames == 2  # 3 and 4 lost, across feeds
    assert dec.dropped_frames == 4


def test_board_time_unwraps_across_feeds():
    z = np.zeros((2, 3))
    dec = proto.FrameDecoder()
    a = dec.feed(proto.encode_data_frames(np.arange(2), np.array([2**32 - 20_000, 2**32 - 10_000]), z, z, z, z, np.zeros(2)))
    b = dec.feed(proto.encode_data_frames(np.arange(2, 4), np.array([0, 10_000]), z, z, z, z, np.zeros(2)))
    assert np.allclose(np.diff(np.concatenate([a.board_time_s, b.board_time_s])), 0.01)


def test_every_reply_type_round_trips():
    dec = proto.FrameDecoder()
    msgs = [(proto.reply_type(c), bytes(range(i))) for i, c in enumerate(proto.COMMANDS)] + [(proto.FrameType.NAK, b"\x13\x03")]
    out = dec.feed(b"".join(proto.encode_frame(t, p) for t, p in msgs))
    assert out.replies == msgs and out.crc_errors == 0
    assert proto.parse_nak(b"\x13\x03") == (0x13, proto.NakCode.BAD_VALUE)
    assert proto.parse_identity(b"v;m;s;f") == {"vendor": "v", "model": "m", "serial": "s", "firmware": "f"}
    assert proto.parse_config(proto.encode_config(100, 40, True, False, 115200)) == {
        "odr_hz": 100, "moving_avg_n": 40, "streaming": True, "sensor_power": False, "baud": 115200}
    assert proto.parse_bit(b"\x04\x00") == 4


def test_unknown_types_are_garbage_for_the_host_but_frames_for_the_board():
    frame = proto.encode_frame(0x3C, b"x")
    assert proto.FrameDecoder().feed(frame).garbage_bytes == len(frame)
    assert proto.FrameDecoder(accept_unknown_types=True).feed(frame).replies == [(0x3C, b"x")]


def test_long_false_header_inside_a_frame_does_not_hold_back_later_frames():
    # an IDENTIFY reply whose text contains a header claiming a 127-byte payload, then a config reply
    first = proto.encode_frame(proto.reply_type(proto.FrameType.IDENTIFY), b"v;m;\xa5\x5a\x90\x7f;f")
    second = proto.encode_frame(proto.reply_type(proto.FrameType.GET_CONFIG), proto.encode_config(100, 1, False, True, 115200))
    dec = proto.FrameDecoder()
    out = dec.feed(first + second)
    assert [t for t, _ in out.replies] == [0x90, 0x97]
    assert out.garbage_bytes == 0 and dec.pending_bytes == 0


def test_trailing_a5_is_held_until_decidable():
    frame = proto.encode_frame(0x91)
    dec = proto.FrameDecoder()
    assert dec.feed(b"\x00\xa5").garbage_bytes == 1 and dec.pending_bytes == 1
    assert dec.feed(b"\x5a" + frame[2:]).replies == [(0x91, b"")]
    assert dec.feed(b"\x07").garbage_bytes == 1 and dec.pending_bytes == 0


def test_sync_word_inside_payload_makes_no_false_frame():
    z = np.zeros((2, 3), dtype=np.int16)
    g = z.copy()
    g[0] = [0x5AA5, 0x2001, 0]  # little-endian bytes A5 5A 01 20: a data-frame header inside the payload
    b = proto.FrameDecoder().feed(proto.encode_data_frames(np.arange(2), np.arange(2), g.view(np.int16), z, z, z, np.zeros(2)))
    assert b.frames_ok == 2 and b.crc_errors == 0 and b.garbage_bytes == 0


@settings(max_examples=300)
@given(st.binary(max_size=400), st.binary(max_size=100))
def test_decoder_never_raises_on_arbitrary_bytes(a, b):
    dec = proto.FrameDecoder()
    x = dec.feed(a)
    y = dec.feed(b)
    # every byte is in a good frame, counted as garbage, or held for the next feed
    assert frame_bytes(x) + x.garbage_bytes + frame_bytes(y) + y.garbage_bytes + dec.pending_bytes == len(a) + len(b)
    # a CRC error is a sync word starting a frame header whose CRC fails: never more than the sync words
    assert x.crc_errors + y.crc_errors <= (a + b).count(SYNC)
    assert dec.frames_ok == x.frames_ok + y.frames_ok

"""Frame decode speed: batch FrameDecoder vs a per-frame loop (struct + binascii.crc_hqx).

Both decode the same byte stream in the same run: N data frames of 38 bytes with about 1 % of
them corrupted by a bit flip and a few garbage runs mixed in, fed in 1 MiB chunks (``--chunk``).

    python benchmarks/bench_decode.py [--frames 1000000] [--repeat 3] [--json]
"""

from __future__ import annotations

import argparse
import binascii
import json
import struct
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from drivers import acs_protocol as proto  # noqa: E402

CHUNK = 1 << 20  # bytes per feed (both decoders); --chunk to change


def make_stream(n: int, seed: int = 7) -> tuple[bytes, int]:
    rng = np.random.default_rng(seed)
    v = lambda: rng.integers(-2000, 2000, (n, 3)).astype(np.int16)  # noqa: E731
    frames = bytearray(proto.encode_data_frames(np.arange(n) % 65536, np.arange(n) * 10_000 % 2**32, v(), v(), v(), v(), np.full(n, 3)))
    bad = rng.choice(n, n // 100, replace=False)
    for k in bad:  # one bit flip in the payload of 1 % of the frames
        frames[k * 38 + int(rng.integers(4, 36))] ^= 1 << int(rng.integers(0, 8))
    out = bytearray()
    step = max(1, n // 20)
    for i in range(0, n, step):  # 20 garbage runs of 17 bytes
        out += frames[i * 38:(i + step) * 38] + bytes(rng.integers(0, 0xA4, 17, dtype=np.uint8))
    return bytes(out), n - len(bad)


_HDR = struct.Struct("<2sBB")
_DATA = struct.Struct("<HI3h3h3h3hH")


def loop_decode(stream: bytes) -> int:
    """Straightforward per-frame decoder: scan for sync, check CRC with crc_hqx, unpack with struct."""
    good = 0
    tail = b""
    rows = []
    for off in range(0, len(stream), CHUNK):
        buf = tail + stream[off:off + CHUNK]
        i, n = 0, len(buf)
        while True:
            i = buf.find(b"\xa5\x5a", i)
            if i < 0 or i + 4 > n:
                tail = buf[i:] if i >= 0 else buf[-1:]
                break
            _, ftype, ln = _HDR.unpack_from(buf, i)
            if ftype != 1 or ln != 32:
                i += 1
                continue
            if i + 38 > n:
                tail = buf[i:]
                break
            if binascii.crc_hqx(buf[i + 2:i + 36], 0) != int.from_bytes(buf[i + 36:i + 38], "big"):
                i += 1
                continue
            v = _DATA.unpack_from(buf, i + 4)
            rows.append((v[0], v[1], [x * proto.GYRO_DPS_PER_LSB for x in v[2:5]], [x * proto.ACCEL_G_PER_LSB for x in v[5:8]],
                         [x * proto.MAG_UT_PER_LSB for x in v[8:11]], [x * 0.01 for x in v[11:14]], v[14]))
            good += 1
            i += 38
        else:
            tail = b""
    return good


def batch_decode(stream: bytes) -> int:
    dec = proto.FrameDecoder()
    good = 0
    for off in range(0, len(stream), CHUNK):
        good += dec.feed(stream[off:off + CHUNK]).frames_ok
    return good


def best(fn, stream: bytes, repeat: int) -> tuple[float, int]:
    times, result = [], 0
    for _ in range(repeat):
        t0 = time.perf_counter()
        result = fn(stream)
        times.append(time.perf_counter() - t0)
    return min(times), result


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=1_000_000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--chunk", type=int, default=CHUNK, help="bytes per feed (default 1 MiB)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    globals()["CHUNK"] = args.chunk
    stream, expected = make_stream(args.frames)
    t_batch, n_batch = best(batch_decode, stream, args.repeat)
    t_loop, n_loop = best(loop_decode, stream, args.repeat)
    if not n_batch == n_loop == expected:
        print(f"decoders disagree: batch {n_batch}, loop {n_loop}, expected {expected}", file=sys.stderr)
        return 1
    out = {
        "frames_total": args.frames, "chunk_bytes": args.chunk, "frames_good": expected, "bytes": len(stream),
        "batch_frames_per_s": n_batch / t_batch, "loop_frames_per_s": n_loop / t_loop,
        "ratio_batch_to_loop": t_loop / t_batch,
        "batch_mb_per_s": len(stream) / t_batch / 1e6, "loop_mb_per_s": len(stream) / t_loop / 1e6,
        "targets": {"ratio": 5, "batch_frames_per_s": 5e6},
    }
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        print(f"{args.frames} frames ({len(stream) / 1e6:.1f} MB, {args.frames - expected} corrupted, 20 garbage runs), fed in {args.chunk} B chunks")
        print(f"batch FrameDecoder : {out['batch_frames_per_s'] / 1e6:6.2f} M frames/s  {out['batch_mb_per_s']:7.1f} MB/s  [target >= 5 M frames/s]")
        print(f"per-frame loop     : {out['loop_frames_per_s'] / 1e6:6.2f} M frames/s  {out['loop_mb_per_s']:7.1f} MB/s")
        print(f"ratio batch/loop   : {out['ratio_batch_to_loop']:.1f}x  [target >= 5x]")
    return 0


if __name__ == "__main__":
    sys.exit(main())

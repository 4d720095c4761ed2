"""Modbus poll round trip against the local chamber simulator (a pymodbus TCP server on 127.0.0.1).

Measured in the same run, on the same server and connection type:

* ``driver``: :meth:`drivers.watlow_f4.WatlowF4.read_air_temp_c` (FC 3 of register 100, decoded to
  °C, input-error check, traffic hook) — what a run pays per chamber reading;
* ``raw pymodbus`` (the baseline): ``ModbusTcpClient.read_holding_registers(100, count=1)``;
* ``socket``: a hand-built Modbus TCP ADU over a plain blocking socket (the floor: server + kernel).

    python benchmarks/bench_modbus.py [--polls 2000] [--repeat 3] [--json]

Prints median and p99 round trip (µs) of each, and the driver's ratio to the baseline.
"""

from __future__ import annotations

import argparse
import json
import socket
import struct
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pymodbus.client import ModbusTcpClient  # noqa: E402

from bench.clock import WallClock  # noqa: E402
from bench.sim.chamber import Chamber  # noqa: E402
from bench.sim.watlow_f4_server import WatlowF4Server  # noqa: E402
from drivers.watlow_f4 import WatlowF4  # noqa: E402


def timed(fn, n: int) -> np.ndarray:
    out = np.empty(n)
    for i in range(n):
        t0 = time.perf_counter()
        fn()
        out[i] = time.perf_counter() - t0
    return out * 1e6


def socket_poll(port: int):
    sock = socket.create_connection(("127.0.0.1", port))
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    tid = [0]

    def poll() -> None:
        tid[0] = (tid[0] + 1) & 0xFFFF
        sock.sendall(struct.pack(">HHHBBHH", tid[0], 0, 6, 1, 3, 100, 1))
        need, got = 11, b""  # MBAP 7 + FC + byte count + 2 data bytes
        while len(got) < need:
            chunk = sock.recv(need - len(got))
            if not chunk:
                raise ConnectionError("server closed the connection")
            got += chunk

    return poll, sock.close


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--polls", type=int, default=2000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()

    server = WatlowF4Server(WallClock(), Chamber())
    port = server.start()
    try:
        drv = WatlowF4.open(f"modbus-tcp://127.0.0.1:{port}", timeout_s=1.0)
        raw = ModbusTcpClient("127.0.0.1", port=port, timeout=1.0)
        raw.connect()
        sock_poll, sock_close = socket_poll(port)
        results: dict[str, np.ndarray] = {}
        for _ in range(args.repeat):
            for name, fn in (("driver", drv.read_air_temp_c),
                             ("raw pymodbus", lambda: raw.read_holding_registers(100, count=1, device_id=1)),
                             ("socket", sock_poll)):
                fn()  # warm
                t = timed(fn, args.polls)
                if name not in results or np.median(t) < np.median(results[name]):
                    results[name] = t
        drv.close()
        raw.close()
        sock_close()
    finally:
        server.stop()
    summary = {name: {"median_us": float(np.median(t)), "p99_us": float(np.percentile(t, 99)), "polls": int(t.size)}
               for name, t in results.items()}
    ratio = summary["driver"]["median_us"] / summary["raw pymodbus"]["median_us"]
    if args.json:
        print(json.dumps({"results": summary, "driver_vs_raw_pymodbus_median": ratio}, indent=2))
    else:
        for name, s in summary.items():
            print(f"{name:14s} median {s['median_us']:8.1f} us   p99 {s['p99_us']:8.1f} us   ({s['polls']} polls, best of {args.repeat})")
        print(f"driver / raw pymodbus (median): {ratio:.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())

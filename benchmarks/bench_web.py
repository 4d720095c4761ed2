"""Web station speed (docs/benchmarks.md, "Web station"): against the size of the stream
(10^4, 10^5, 10^6 rows of a 3-axis column at 1 kHz):

1. time to first plot of a run page: the server's decimated answer for the whole stream at 1200 px
   (cold: first request, building the block cache; warm: the next one) against the baseline of
   reading the whole column with h5py (``read_stream``) and encoding it undecimated as JSON; and
   in chromium, from navigation to the plot drawn;
2. delay from a sample written to the run file (by another process, as ``bench run`` writes) to the
   live page showing it (the page polls every second).

    python benchmarks/bench_web.py [--sizes 10000,100000,1000000] [--live-samples 3]

Needs chromium and playwright for the browser figures (skipped otherwise, said so).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.record import read_stream  # noqa: E402
from bench.web.decimate import StreamCache, decimate  # noqa: E402
from tests.browser import Server, make_run_file  # noqa: E402

PX = 1200
RATE_HZ = 1000.0

LIVE_WRITER = textwrap.dedent("""
    import sys, time
    import numpy as np
    from pathlib import Path
    from tests.browser import make_run_file
    rows, n = int(sys.argv[2]), int(sys.argv[3])
    rec = make_run_file(Path(sys.argv[1]), rows=rows, procedure="live", rate_hz=1000.0, close=False)
    t = rows / 1000.0
    rec.tick(t); rec.flush()
    print("ready", rec.path.name, flush=True)
    for k in range(n + 3):
        end = time.monotonic() + 2.0
        while time.monotonic() < end:      # keep the heartbeat fresh meanwhile
            time.sleep(0.2); rec.tick(t)
        t += 1.0
        rec.append("board", np.array([t]), gyro=np.array([[0.0, 0.0, 0.0]]), temp=np.array([20.0]))
        rec.flush()
        print(f"{t!r} {time.time()!r}", flush=True)
    rec.close("completed")
""")


def _median(xs: list[float]) -> float:
    s = sorted(xs)
    return s[len(s) // 2] if s else float("nan")


def server_side(path: Path) -> dict[str, float]:
    """Decimated answer (cold and warm) against the baseline (whole column read and JSON-encoded)."""
    out = {}
    cache = StreamCache()
    t0 = time.perf_counter()
    d = decimate(path, "board", "gyro", t0=None, t1=None, px=PX, cache=cache)
    out["decimated_cold_ms"] = (time.perf_counter() - t0) * 1e3
    warm = []
    for _ in range(5):
        t0 = time.perf_counter()
        d = decimate(path, "board", "gyro", t0=None, t1=None, px=PX, cache=cache)
        warm.append((time.perf_counter() - t0) * 1e3)
    out["decimated_warm_ms"] = _median(warm)
    out["decimated_bytes"] = len(json.dumps(d))
    out["decimated_points"] = d["points"]
    t0 = time.perf_counter()
    whole = read_stream(path, "board", ["gyro"])
    body = json.dumps({"t": whole["time"].tolist(), "gyro": whole["gyro"].tolist()})
    out["baseline_whole_ms"] = (time.perf_counter() - t0) * 1e3
    out["baseline_bytes"] = len(body)
    return out


def browser_first_plot(browser, server: Server, run_id: str, repeats: int = 3) -> float:
    """Median ms from navigation to the gyro plot drawn."""
    times = []
    for _ in range(repeats):
        page = browser.new_context(bypass_csp=True).new_page()  # the benchmark evaluates its wait in the page
        t0 = time.perf_counter()
        page.goto(server.url + "run?id=" + run_id)
        page.wait_for_function("(document.querySelector(\"canvas[data-key=board][data-column=gyro]\") || {dataset: {}}).dataset.updates >= 1",
                               polling="raf", timeout=120_000)
        times.append((time.perf_counter() - t0) * 1e3)
        page.context.close()
    return _median(times)


def live_delay(browser, runs: Path, rows: int, samples: int) -> list[float]:
    """Seconds from a sample flushed by another process to the live page showing it."""
    live_dir = runs / f"live{rows}"
    w = subprocess.Popen([sys.executable, "-c", LIVE_WRITER, str(live_dir), str(rows), str(samples)], cwd=ROOT,
                         stdout=subprocess.PIPE, text=True)
    server = None
    delays = []
    try:
        first = w.stdout.readline().split()
        assert first and first[0] == "ready", first
        server = Server(live_dir)
        page = browser.new_context(bypass_csp=True).new_page()
        page.goto(server.url + "run?id=" + first[1])
        page.wait_for_selector("#live-panel", timeout=60_000)
        sel = "canvas[data-key=board][data-column=gyro]"
        for _ in range(samples + 1):
            t_text, wall = w.stdout.readline().split()
            want = float(t_text)
            page.wait_for_function(f"+((document.querySelector(\"{sel}\") || {{dataset: {{}}}}).dataset.tLast || 0) >= {want}",
                                   polling=20, timeout=30_000)
            delays.append(time.time() - float(wall))
        page.context.close()
        return delays[1:]  # the first one also waits for the page to settle
    finally:
        if server is not None:
            server.stop()
        w.kill()
        w.wait(timeout=10)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", default="10000,100000,1000000")
    ap.add_argument("--live-samples", type=int, default=3)
    args = ap.parse_args()
    sizes = [int(x) for x in args.sizes.split(",")]
    try:
        from tests.browser import launch_browser

        browsers = launch_browser()
        browser = next(browsers)
    except BaseException as exc:  # noqa: BLE001 - pytest.skip raises its own exception type
        print(f"no browser figures: {exc}")
        browser = None
    with tempfile.TemporaryDirectory() as tmp:
        runs = Path(tmp) / "runs"
        rows_out = []
        for n in sizes:
            path = make_run_file(runs, rows=n, procedure=f"bench{n}", rate_hz=RATE_HZ)
            r = {"rows": n, "file_mb": path.stat().st_size / 1e6, **server_side(path)}
            rows_out.append((n, path, r))
        if browser is not None:
            server = Server(runs)
            try:
                for n, path, r in rows_out:
                    r["browser_first_plot_ms"] = browser_first_plot(browser, server, path.name)
            finally:
                server.stop()
            for n, path, r in rows_out:
                d = live_delay(browser, Path(tmp), n, args.live_samples)
                r["live_delay_s_median"] = _median(d)
                r["live_delay_s_max"] = max(d)
    print(f"{'rows':>9} {'file MB':>8} {'decim cold ms':>13} {'decim warm ms':>13} {'points':>6} {'kB':>6} "
          f"{'baseline ms':>11} {'baseline kB':>11} {'browser ms':>10} {'live s med/max':>14}")
    for n, _path, r in rows_out:
        live = f"{r['live_delay_s_median']:.2f}/{r['live_delay_s_max']:.2f}" if "live_delay_s_median" in r else "-"
        br = f"{r['browser_first_plot_ms']:.0f}" if "browser_first_plot_ms" in r else "-"
        print(f"{n:>9,} {r['file_mb']:>8.1f} {r['decimated_cold_ms']:>13.1f} {r['decimated_warm_ms']:>13.1f} {r['decimated_points']:>6} "
              f"{r['decimated_bytes'] / 1e3:>6.0f} {r['baseline_whole_ms']:>11.0f} {r['baseline_bytes'] / 1e3:>11.0f} {br:>10} {live:>14}")
    if browser is not None:
        try:
            next(browsers)
        except StopIteration:
            pass


if __name__ == "__main__":
    main()

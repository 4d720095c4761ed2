"""Run the diagnosis with a single BLAS thread.

The fits are thousands of small products and solves (block Grams of a dozen columns, 10×10
systems, complex dot products over one table-angle harmonic at a time). A multi-threaded OpenBLAS
gains nothing on them and, on a machine shared with other work, its spinning threads make them
tens of times slower (measured: the table-angle spectrum of 28,800 rows took 5.4 s with the default
threads on a loaded 2-core machine, 0.19 s with one). :func:`single_thread` sets the OpenBLAS
thread count to 1 for the duration of a ``with`` block and restores it, through ``threadpoolctl``
when installed, else through OpenBLAS's own ``*_set_num_threads`` entry point found in the
process's loaded libraries (Linux); elsewhere it does nothing.
"""

from __future__ import annotations

import contextlib
import ctypes
from typing import Iterator

_SYMBOLS = (("scipy_openblas_get_num_threads64_", "scipy_openblas_set_num_threads64_"),
            ("scipy_openblas_get_num_threads", "scipy_openblas_set_num_threads"),
            ("openblas_get_num_threads64_", "openblas_set_num_threads64_"),
            ("openblas_get_num_threads", "openblas_set_num_threads"))


def _openblas() -> list[tuple[object, object]]:
    """(get, set) entry points of every OpenBLAS loaded in this process."""
    out = []
    try:
        with open("/proc/self/maps", encoding="utf-8") as fh:
            paths = sorted({line.split()[-1] for line in fh if "openblas" in line.lower() and ".so" in line})
    except OSError:
        return out
    for path in paths:
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for get_name, set_name in _SYMBOLS:
            get_fn, set_fn = getattr(lib, get_name, None), getattr(lib, set_name, None)
            if get_fn is not None and set_fn is not None:
                get_fn.restype = ctypes.c_int
                set_fn.argtypes = [ctypes.c_int]
                out.append((get_fn, set_fn))
                break
    return out


@contextlib.contextmanager
def single_thread() -> Iterator[None]:
    """One BLAS thread inside the block (restored afterwards)."""
    try:
        from threadpoolctl import threadpool_limits  # type: ignore[import-not-found]
    except ImportError:
        threadpool_limits = None
    if threadpool_limits is not None:
        with threadpool_limits(limits=1, user_api="blas"):
            yield
        return
    libs = _openblas()
    saved = []
    for get_fn, set_fn in libs:
        try:
            saved.append((set_fn, int(get_fn())))
            set_fn(1)
        except Exception:  # noqa: BLE001 - a library we cannot drive is left as it is
            continue
    try:
        yield
    finally:
        for set_fn, n in saved:
            try:
                set_fn(n)
            except Exception:  # noqa: BLE001
                pass

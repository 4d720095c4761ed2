"""Where bench keeps what it can compute again: ``$XDG_CACHE_HOME/bench`` (default ``~/.cache/bench``).

Everything under it is an optimisation (pint's parsed unit definitions, the installed kinds' entry
points): deleting it is always safe, and bench works, only slower, where it cannot be written.
"""

from __future__ import annotations

import os
from pathlib import Path


def user_cache_dir(name: str) -> Path:
    """The cache directory ``name`` of bench: ``$XDG_CACHE_HOME/bench/NAME`` (default
    ``~/.cache/bench/NAME``); not created here."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "bench" / name

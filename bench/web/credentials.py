"""Whether a run file still holds a credential, before the web station serves it.

Run files written since issue 31 hold none (the recorder masks them, :mod:`bench.redact`), but labs
keep older files whose ``/config/text`` holds, e.g., a catalogue URL with its password.
``GET /api/file`` refuses such a file (403, naming where the credential is without quoting it); the
file stays on the station's disk as it was, for whoever can read that disk. The texts searched are
those a run file keeps as text: the procedure and config texts, the root attributes, the
instruments' identities and every event but the instrument traffic (message, source and data).
"""

from __future__ import annotations

import threading
from pathlib import Path


class CredentialCheck:
    """:meth:`found_in` with its answers kept while a file does not change (size and time)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._seen: dict[str, tuple[tuple[int, int], str]] = {}

    def found_in(self, path: Path) -> str:
        """Where the run file ``path`` holds a credential (``"a URL password on line 2 of
        /config/text"``), ``""`` when it holds none. :class:`~bench.errors.InputError` for a file
        that is not a readable run file."""
        from bench.record import read_run_summary
        from bench.redact import find_secrets

        st = path.stat()
        stamp = (st.st_mtime_ns, st.st_size)
        with self._lock:
            seen = self._seen.get(str(path))
        if seen is not None and seen[0] == stamp:
            return seen[1]
        s = read_run_summary(path, traffic=False)
        texts = [("/config/text", s.config_text), ("/procedure/text", s.procedure_text)]
        texts += [(f"attribute {k}", str(v)) for k, v in s.attrs.items()]
        texts += [(f"/instruments/{n}", " ".join(f"{k}={v}" for k, v in info.items())) for n, info in s.instruments.items()]
        texts += [(f"event {e.kind} at {e.t_s:.3f} s", f"{e.source} {e.message} {e.data.decode('utf-8', 'replace')}") for e in s.events]
        found = next((f"{hits[0]} of {where}" for where, text in texts for hits in [find_secrets(text)] if hits), "")
        with self._lock:
            self._seen[str(path)] = (stamp, found)
        return found

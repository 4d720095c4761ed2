"""The structure of a new run file, written before SWMR mode (HDF5 cannot add objects or attributes
under SWMR): the root attributes, the procedure and config texts, the instrument identities, the
groups and the event and heartbeat datasets. Streams are added by :mod:`bench.record.streams`.

Times: ``started`` in UTC; the heartbeat holds [wall time s since the Unix epoch, run time s].
"""

from __future__ import annotations

import getpass
import socket
import time
from datetime import datetime
from typing import Mapping

import h5py
import numpy as np

from bench.record import layout
from bench.redact import redact
from bench.record.events import create_event_datasets

HEARTBEAT_UNITS = "s"


def write_skeleton(
    f: h5py.File,
    *,
    procedure_name: str,
    procedure_text: str,
    procedure_path: str,
    config_text: str,
    config_path: str,
    mode: str,
    operator: str | None,
    software_version: str,
    started: datetime,
    identity: Mapping[str, str] | None = None,
) -> None:
    """Write everything a run file holds from its creation: root attributes (``status`` running,
    ``ended_utc`` and ``abort_reason`` empty; the ``identity`` attributes given, see
    :data:`layout.IDENTITY_ATTRS`), texts, the empty instrument and stream groups, the
    empty event datasets and the heartbeat ([now, 0 s]). ``operator`` defaults to the login name.
    Every text goes through :func:`bench.redact.redact` first: no credential is stored."""
    a = f.attrs
    a[layout.ATTR_FORMAT_VERSION] = np.int64(layout.FORMAT_VERSION)
    texts = {
        layout.ATTR_SOFTWARE_VERSION: software_version, layout.ATTR_PROCEDURE_NAME: procedure_name,
        layout.ATTR_PROCEDURE_PATH: procedure_path, layout.ATTR_CONFIG_PATH: config_path,
        layout.ATTR_OPERATOR: operator if operator is not None else login_name(), layout.ATTR_HOST: socket.gethostname(),
        layout.ATTR_MODE: mode, layout.ATTR_STARTED_UTC: layout.utc_text(started), layout.ATTR_ENDED_UTC: "",
        layout.ATTR_STATUS: layout.STATUS_RUNNING, layout.ATTR_ABORT_REASON: "", **(identity or {}),
    }
    for key, value in texts.items():
        a[key] = redact(str(value))
    write_text(f.create_group(layout.PROCEDURE), redact(procedure_text))
    write_text(f.create_group(layout.CONFIG), redact(config_text))
    f.create_group(layout.INSTRUMENTS)
    f.create_group(layout.STREAMS)
    create_event_datasets(f)
    hb = f.create_dataset(layout.HEARTBEAT, data=np.array([time.time(), 0.0]), dtype="f8")
    hb.attrs[layout.ATTR_UNITS] = HEARTBEAT_UNITS
    hb.attrs[layout.ATTR_FIELDS] = ",".join(layout.HEARTBEAT_FIELDS)


def write_text(g: h5py.Group, text: str) -> None:
    """Store ``text`` exactly as a fixed-length utf-8 string dataset ``text`` (not variable length)."""
    raw = text.encode(layout.TEXT_ENCODING, errors="surrogateescape")
    ds = g.create_dataset(layout.TEXT, data=np.array(raw, dtype=f"S{max(len(raw), 1)}"))
    ds.attrs[layout.ATTR_ENCODING] = layout.TEXT_ENCODING
    ds.attrs[layout.ATTR_LENGTH_BYTES] = np.int64(len(raw))


def write_identity(f: h5py.File, name: str, info: dict[str, str]) -> None:
    """``/instruments/<name>`` with the identity strings as attributes, in the order given."""
    g = f[layout.INSTRUMENTS].create_group(name, track_order=True)
    for k, v in info.items():
        g.attrs[str(k)] = redact(str(v))


def login_name() -> str:
    """The login name, ``unknown`` when it cannot be determined."""
    try:
        return getpass.getuser()
    except (OSError, KeyError):
        return "unknown"

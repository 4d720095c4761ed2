"""The per-file work of ``bench calibrate METHOD DATA`` and ``bench diagnose DATA``, without the
command line: ``bench/cli_analysis.py`` (one file) and ``bench/fleet`` (many files on workers) call
the same functions, so a fleet's result for a file is the serial command's.

* :func:`calibrate_file`: read the data (a run file, a measured-data CSV, a mapped foreign file or,
  for rate-transfer, a summary CSV) and run the method; a :class:`CalibrationResult`.
* :func:`diagnose_file`: read the data and diagnose it; the result and the dataset (for the report).
* :func:`diagnose_files`: several runs of one unit (``bench diagnose A B ...``): the
  :class:`~bench.analysis.diagnose.runs.RunsResult`.
* :func:`json_text`: the ``--json`` text of a result (numpy values as plain ones), byte for byte
  what the commands print.

Light at import (the analyses, numpy and h5py are imported when called): the CLI's parser imports
:data:`METHODS` from here.
"""

from __future__ import annotations

import importlib
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Sequence

from bench.errors import InputError

if TYPE_CHECKING:
    from bench.analysis.dataset import Dataset
    from bench.analysis.diagnose import DiagnoseResult
    from bench.analysis.diagnose.runs import RunsResult
    from bench.analysis.result import CalibrationResult

METHODS: dict[str, tuple[str, str]] = {
    "thermal": ("bench.analysis.thermal_cal", "calibrate"),
    "rate-transfer": ("bench.analysis.rate_transfer", "calibrate"),
    "two-level": ("bench.analysis.two_level", "calibrate"),
    "gauss-newton": ("bench.analysis.gauss_newton", "calibrate"),
    "six-position": ("bench.analysis.six_position", "calibrate"),
    "noise": ("bench.analysis.noise_cal", "calibrate"),
    "moving-average": ("bench.analysis.noise_cal", "calibrate_moving_average"),
}
"""``bench calibrate`` method -> (module, function(Dataset, **options) -> CalibrationResult)."""

Say = Callable[[str], None]
"""A progress or note sink: called with one line of text."""


def _quiet(_text: str) -> None:
    """The sink that says nothing."""


def calibration_options(method: str, *, degree: int | None = None, sensor: str | None = None,
                        sections: Path | None = None, local_g: str | None = None) -> dict[str, Any]:
    """The keyword options of ``method`` from ``--degree`` (thermal), ``--sensor`` (gauss-newton),
    ``--sections`` and ``--local-g`` (six-position); an option given to a method it does not apply
    to is bad input (:class:`InputError` naming it)."""
    opts: dict[str, Any] = {}
    for value, flag, key in ((sections, "--sections", "sections"), (local_g, "--local-g", "local_g")):
        if value is not None:
            if method != "six-position":
                raise InputError(f"{flag} applies to the six-position method only", None, flag)
            opts[key] = str(value)
    if degree is not None:
        if method != "thermal":
            raise InputError("--degree applies to the thermal method only", None, "--degree")
        opts["degree"] = degree
    if sensor is not None:
        if method != "gauss-newton":
            raise InputError("--sensor applies to the gauss-newton method only", None, "--sensor")
        opts["sensor"] = sensor
    return opts


def load_checked(data: Path, mapping: Sequence[str] | None = None, *, on_note: Say = _quiet) -> "Dataset":
    """The dataset of ``data`` (``mapping``: ``--map`` values for a foreign HDF5/netCDF-4 file); how a
    mapped file was read (time source, dropped rows) goes to ``on_note``, one note per call. A value
    no measurement has (|v| > 1e9, e.g. 1e300) is refused at its row (:func:`check_magnitudes`)."""
    from bench.analysis.dataset import check_magnitudes
    from bench.analysis.foreign import load_data

    ds, notes = load_data(data, mapping)
    check_magnitudes(ds)
    for note in notes:
        on_note(note)
    return ds


def calibrate_file(method: str, data: Path, mapping: Sequence[str] | None = None, options: dict[str, Any] | None = None,
                   *, progress: Say = _quiet, on_note: Say = _quiet) -> "CalibrationResult":
    """Calibrate with ``method`` (a key of :data:`METHODS`) from the file ``data``; ``options``
    from :func:`calibration_options`. ``progress`` hears what is being done, ``on_note`` how a
    mapped file was read. Raises :class:`InputError` for data the method cannot use."""
    module_name, func_name = METHODS[method]
    module = importlib.import_module(module_name)
    opts = dict(options or {})
    data = Path(data)
    progress(f"reading {data}")
    if method == "rate-transfer" and data.suffix.lower() not in (".h5", ".hdf5") and module.is_summary_csv(data):
        return module.calibrate_summary_csv(data, **opts)
    ds = load_checked(data, mapping, on_note=on_note)
    progress(f"fitting {len(ds):,} rows")
    return getattr(module, func_name)(ds, **opts)


def diagnose_file(data: Path, mapping: Sequence[str] | None = None, model: Path | None = None,
                  *, progress: Say = _quiet, on_note: Say = _quiet,
                  power_on_at: float | None = None) -> tuple["DiagnoseResult", "Dataset"]:
    """Diagnose the file ``data`` against the baseline sensor model (plus ``model``'s known terms):
    the result and the dataset it was made from (for :func:`bench.analysis.diagnose.write_report`).
    ``power_on_at``: the power-on time (s) of data without a ``power_on_s`` column."""
    from bench.analysis.diagnose import diagnose

    progress(f"reading {data}")
    ds = load_checked(Path(data), mapping, on_note=on_note)
    progress(f"{len(ds):,} rows read, preparing")
    return diagnose(ds, model_path=str(model) if model else None, progress=progress, power_on_at=power_on_at), ds


def diagnose_files(data: Sequence[Path], mapping: Sequence[str] | None = None, model: Path | None = None,
                   *, progress: Say = _quiet, on_note: Say = _quiet,
                   power_on_at: Sequence[float | None] | None = None) -> "RunsResult":
    """Diagnose several data files of ONE unit together (:func:`bench.analysis.diagnose.runs.diagnose_runs`):
    each as :func:`diagnose_file` does, then the replication test tied to power-on across them.
    ``power_on_at``: one power-on time (s) per file, or None."""
    from bench.analysis.diagnose.runs import diagnose_runs

    datasets = []
    for path in data:
        progress(f"reading {path}")
        datasets.append(load_checked(Path(path), mapping, on_note=on_note))
    return diagnose_runs(datasets, model_path=str(model) if model else None, progress=progress, power_on_at=power_on_at)


def rows_line(result: "DiagnoseResult") -> str | None:
    """What a diagnosis analysed ("analysed 1,800 rows at 100 Hz"), when it says."""
    prepared = (getattr(result, "_internal", None) or (None,))[0]
    return prepared.rows_line() if hasattr(prepared, "rows_line") else None


def json_text(payload: Any) -> str:
    """The ``--json`` text of a result's ``json`` payload (numpy values as plain ones), as the
    commands print it."""
    return json.dumps(payload, indent=2, default=plain)


def plain(v: Any) -> Any:
    """numpy scalars and arrays as plain Python for JSON/YAML."""
    import numpy as np

    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, Path):
        return str(v)
    raise TypeError(f"not serialisable: {type(v).__name__}")


def plain_tree(v: Any) -> Any:
    """``v`` with every dict key a string and every value plain (:func:`plain`), for YAML."""
    if isinstance(v, dict):
        return {str(k): plain_tree(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [plain_tree(x) for x in v]
    if isinstance(v, (str, int, float, bool)) or v is None:
        return v
    return plain_tree(plain(v))

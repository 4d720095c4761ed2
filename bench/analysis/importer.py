"""``bench import``: a measured-data CSV, or another program's HDF5/netCDF-4 file read through a
column mapping (``--map``, ``bench/analysis/foreign.py``), as a bench run file (mode ``imported``).

The file has one stream, ``imported``, holding every known column of the CSV (units from the
column names; ``time_s`` becomes the stream's ``time``), and the CSV's ``# key: value`` metadata as
attributes of that stream. :func:`bench.analysis.dataset.dataset_from_run` reads it back as the
same :class:`~bench.analysis.dataset.Dataset` the CSV gives, so every analysis command takes either.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from bench import __version__
from bench.analysis.dataset import COLUMNS, Dataset, dataset_from_csv
from bench.analysis.foreign import dataset_from_foreign
from bench.errors import InputError, Location
from bench.record.layout import IMPORTED_STREAM, MODE_IMPORTED
UNITS_BY_SUFFIX = {"_s": "s", "_dps": "deg/s", "_deg": "deg", "_c": "degC", "_torr": "Torr", "_g": "g"}
"""Column-name suffix -> units (the measured-data CSV names carry their units)."""


def column_units(name: str) -> str:
    """Units of a measured-data column from its name (``gyro_x_dps`` -> ``deg/s``)."""
    for suffix, units in UNITS_BY_SUFFIX.items():
        if name.endswith(suffix):
            return units
    return "1"


def import_csv(csv_path: Path, out_path: Path) -> int:
    """Write ``csv_path`` as run file ``out_path`` (refused if it exists); returns the row count."""
    return write_imported_run(dataset_from_csv(csv_path), csv_path, out_path)


def import_data(path: Path, out_path: Path, mapping=None) -> Dataset:
    """Write a measured-data CSV, or with ``mapping`` (``--map`` values) another program's
    HDF5/netCDF-4 file (``bench/analysis/foreign.py``), as run file ``out_path``; returns the dataset
    written. A bench run file, or an HDF5 file given without a mapping, is refused saying why."""
    from bench.analysis.foreign import foreign_file_error, is_run_file

    path = Path(path)
    if mapping:
        ds = dataset_from_foreign(path, mapping)
    else:
        run = is_run_file(path)
        if run:
            raise InputError("is already a bench run file; there is nothing to import", Location(path))
        if run is False:
            raise foreign_file_error(path)
        ds = dataset_from_csv(path)
    write_imported_run(ds, path, out_path)
    return ds


def write_imported_run(ds: Dataset, source: Path, out_path: Path) -> int:
    """Write dataset ``ds`` (read from ``source``) as run file ``out_path`` (refused if it exists):
    stream ``imported`` with every known column, the metadata in an ``import`` note. Returns the
    row count."""
    from bench.record import Column, RunRecorder

    out_path = Path(out_path)
    if out_path.exists():
        raise InputError(f"{out_path} exists; run files are never overwritten", None, "-o")
    names = [c for c in COLUMNS if c in ds.columns and c != "time_s"]
    rec = RunRecorder.create(out_path.parent if str(out_path.parent) else Path("."), procedure_name="imported",
                             procedure_text="", procedure_path="", config_text="", config_path="",
                             mode=MODE_IMPORTED, software_version=__version__)
    key = rec.add_stream(IMPORTED_STREAM, [Column(n, column_units(n)) for n in names])
    rec.start()
    rec.append(key, ds.columns["time_s"], **{n: ds.columns[n] for n in names})
    rec.event("note", "import", json.dumps({"source": str(source), "meta": ds.meta}), t_s=0.0)
    rec.close("completed")
    try:
        os.link(rec.path, out_path)  # fails if out_path appeared meanwhile: never overwrites
    except FileExistsError:
        raise InputError(f"{out_path} exists; run files are never overwritten (the import is in {rec.path})", None, "-o") from None
    except OSError:  # a filesystem without hard links
        if out_path.exists():
            raise InputError(f"{out_path} exists; run files are never overwritten (the import is in {rec.path})", None, "-o") from None
        os.rename(rec.path, out_path)
        return len(ds)
    os.unlink(rec.path)
    return len(ds)

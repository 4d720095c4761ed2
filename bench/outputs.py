"""Writing an output file so that no reader ever sees half of it: a hidden sibling moved into place
(``bench report -o``, ``bench calibrate -o``, the fleet's outputs).

Only a regular file is ever replaced: an output named as a device (``/dev/full``, ``/dev/null``), a
FIFO, a socket, a directory or a symbolic link is refused (:func:`refuse_special`), with
``--force`` too; before, ``-o /dev/full --force`` replaced the device node with an HTML file.
"""

from __future__ import annotations

import os
import stat
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from bench.errors import InputError


@contextmanager
def output_file(path: Path, option: str, *, force: bool = False) -> Iterator[Path]:
    """Where to write the output ``path``: a hidden sibling, moved to ``path`` when the block ends
    without an exception (removed otherwise). An existing ``path`` is replaced only with ``force``
    and only once the new file is complete; without ``force`` a file that appeared meanwhile is not
    overwritten (:class:`InputError`, ``option`` names the option). The writer may refuse an
    existing file: the sibling never exists beforehand."""
    path = Path(path)
    refuse_special(path, option)
    tmp = path.with_name(f".{path.stem}.partial-{os.getpid()}{path.suffix}")
    try:
        yield tmp
        if os.path.exists(tmp):  # else the writer wrote nothing (e.g. refused)
            refuse_special(path, option)  # also one made while the output was written
            _move_into_place(tmp, path, option, force)
    finally:
        if os.path.lexists(tmp):
            os.unlink(tmp)


def _move_into_place(tmp: Path, path: Path, option: str, force: bool) -> None:
    try:
        if force:
            os.replace(tmp, path)
            return
        try:
            os.link(tmp, path)  # fails if path exists: never overwrites
        except FileExistsError:
            raise exists_error(path, option) from None
        except OSError:  # a filesystem without hard links
            if os.path.lexists(path):
                raise exists_error(path, option) from None
            os.rename(tmp, path)
    except OSError as exc:
        raise InputError(f"cannot write {path}: {exc.strerror or exc}", None, option) from None


_KINDS = ((stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a FIFO"),
          (stat.S_ISSOCK, "a socket"), (stat.S_ISDIR, "a directory"), (stat.S_ISLNK, "a symbolic link"))


def refuse_special(path: Path, option: str) -> None:
    """:class:`InputError` (naming ``option``) when ``path`` exists and is not a regular file: an
    output only ever creates or replaces a regular file (``--force`` included)."""
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return
    except (OSError, ValueError) as exc:  # ValueError: a NUL in the name
        raise InputError(f"cannot write {path}: {getattr(exc, 'strerror', None) or exc}", None, option) from None
    if stat.S_ISREG(mode):
        return
    kind = next((k for test, k in _KINDS if test(mode)), "not a regular file")
    raise InputError(f"{path} is {kind}: an output only creates or replaces a regular file (--force too); name a file", None, option)


def exists_error(path: Path, option: str) -> InputError:
    """The refusal of an output that exists (exit 2), naming ``option``."""
    return InputError(f"{path} exists; choose another name or delete it (--force overwrites it)", None, option)

"""The kind records without generated code (bench/kinds/frozen.py) and the entry points kept on disk
between runs (bench/kinds/entry_cache.py): both exist for start-up time (docs/benchmarks.md), and
neither may change what a lab sees.

The distributions here are real ``.dist-info`` directories on a ``sys.path`` of their own, read by
the real :mod:`importlib.metadata`; nothing is imported from them.
"""

from __future__ import annotations

import copy
import dataclasses
import importlib.metadata as md
import os
import pickle
import sys

import pytest

from bench.kinds import FieldSpec, Kind, Signal, entry_cache, registry
from bench.kinds.frozen import Frozen

GROUP = registry.GROUP


# ---- records: frozen dataclasses in all but their making -----------------------------------------
@dataclasses.dataclass(frozen=True)
class _AsDataclass:
    kind: str
    units: str = ""
    numbers: tuple[int, int] = (0, 999)


class _AsFrozen(Frozen):
    kind: str
    units: str = ""
    numbers: tuple[int, int] = (0, 999)


def test_a_frozen_record_behaves_as_the_frozen_dataclass_it_replaces():
    for args, kwargs in [(("quantity",), {}), (("quantity", "s"), {"numbers": (1, 3)}), ((), {"kind": "int", "units": "Hz"})]:
        d, f = _AsDataclass(*args, **kwargs), _AsFrozen(*args, **kwargs)
        assert repr(f) == repr(d).replace("_AsDataclass", "_AsFrozen")
        assert (f.kind, f.units, f.numbers) == (d.kind, d.units, d.numbers)
        assert f == _AsFrozen(*args, **kwargs) and hash(f) == hash(_AsFrozen(*args, **kwargs)) and hash(f) == hash(
            dataclasses.astuple(d))
    a = _AsFrozen("quantity", "s")
    match a:
        case _AsFrozen(kind, units, numbers):
            assert (kind, units, numbers) == ("quantity", "s", (0, 999)) and _AsFrozen.__match_args__ == _AsDataclass.__match_args__
    assert a != _AsFrozen("quantity", "Hz") and a != _AsDataclass("quantity", "s") and a != ("quantity", "s", (0, 999))
    assert a.replace(units="Hz") == _AsFrozen("quantity", "Hz") and a.units == "s"
    for bad in (lambda: setattr(a, "units", "Hz"), lambda: delattr(a, "units"), lambda: setattr(a, "other", 1)):
        with pytest.raises(AttributeError):  # a frozen dataclass raises FrozenInstanceError, an AttributeError
            bad()
    for call, words in [(lambda: _AsFrozen(), "missing required argument(s): 'kind'"),
                        (lambda: _AsFrozen("a", kind="b"), "multiple values for argument 'kind'"),
                        (lambda: _AsFrozen("a", colour=1), "unexpected keyword argument 'colour'"),
                        (lambda: _AsFrozen("a", "b", (1, 2), 4), "takes 3 positional arguments but 4 were given")]:
        with pytest.raises(TypeError, match=words.replace("(", r"\(").replace(")", r"\)")):
            call()
    with pytest.raises(TypeError, match="without a default follows"):
        type("Bad", (Frozen,), {"__annotations__": {"a": "int", "b": "int"}, "a": 1})


def test_installed_kind_records_survive_pickle_copy_and_replace():
    for kind in registry.kinds().values():
        assert isinstance(kind, Kind) and isinstance(kind, Frozen)
        assert pickle.loads(pickle.dumps(kind)) == kind
        assert copy.deepcopy(kind) == kind and copy.copy(kind) == kind
        moved = kind.replace(package="elsewhere")
        assert moved.package == "elsewhere" and moved.name == kind.name and kind.package != "elsewhere"
    s = Signal("ch*", "degC", "unit_temp", numbers=(101, 399))
    assert s.matches("ch101") and not s.matches("ch400") and s.shown == "chNNN"
    assert FieldSpec("quantity", "s") == FieldSpec(kind="quantity", units="s") and not hasattr(FieldSpec("int"), "__dict__")


# ---- the entry points, cached ------------------------------------------------------------------
def _dist(site, name: str, entry_points: str | None, version: str = "1.0"):
    info = site / f"{name}-{version}.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n")
    if entry_points is not None:
        (info / "entry_points.txt").write_text(entry_points)
    return info


def _later(path, seconds: float = 1.0) -> None:
    """Move ``path``'s modification time on (a file system's clock may tick coarser than our steps)."""
    t = os.stat(path).st_mtime_ns + int(seconds * 1e9)
    os.utime(path, ns=(t, t))


@pytest.fixture
def site(tmp_path, monkeypatch):
    """A ``sys.path`` of one directory holding a kind's distribution and one without entry points,
    and a cache directory of this test's own."""
    site = tmp_path / "site"
    site.mkdir()
    _dist(site, "lab_kind", f"[{GROUP}]\nfoo = lab_kind:KIND\n[console_scripts]\nlab = lab_kind:main\n")
    _dist(site, "plain_lib", None)
    monkeypatch.setattr(sys, "path", [str(site)])
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    return site


def _no_metadata(monkeypatch):
    def refuse(**_):
        raise AssertionError("the metadata was read: the cache was not used")

    monkeypatch.setattr(md, "entry_points", refuse)


def test_the_cache_gives_what_the_metadata_says_until_something_is_installed(site, monkeypatch):
    first = entry_cache.entries(GROUP)
    assert first == [("lab_kind", "foo", "lab_kind:KIND")] == entry_cache.scan(GROUP)[0]
    (cached,) = (site.parent / "cache" / "bench" / "kinds").glob("*.txt")
    with monkeypatch.context() as m:
        _no_metadata(m)
        assert entry_cache.entries(GROUP) == first  # unchanged: read from the cache
    _dist(site, "other_kind", f"[{GROUP}]\nbar = other_kind.records:KIND [extra]\n")
    _later(site)  # pip install: a new directory in a sys.path entry
    assert sorted(entry_cache.entries(GROUP)) == [("lab_kind", "foo", "lab_kind:KIND"),
                                                  ("other_kind", "bar", "other_kind.records:KIND [extra]")]
    eps = site / "lab_kind-1.0.dist-info" / "entry_points.txt"
    eps.write_text(f"[{GROUP}]\nfoo = lab_kind.v2:KIND\n")
    _later(eps)  # a declaring distribution's entry points edited in place
    assert ("lab_kind", "foo", "lab_kind.v2:KIND") in entry_cache.entries(GROUP)
    with monkeypatch.context() as m:
        _no_metadata(m)
        assert len(entry_cache.entries(GROUP)) == 2
        with pytest.raises(AssertionError, match="metadata was read"):
            entry_cache.entries(GROUP, fresh=True)  # `bench instruments kinds`: always afresh
    cached.write_text(cached.read_text().replace("\nend\n", "\n"))  # a file cut short
    assert len(entry_cache.entries(GROUP)) == 2 and cached.read_text().endswith("\nend\n")


def test_a_cache_that_cannot_be_written_or_read_is_only_slower(site, monkeypatch, tmp_path):
    blocker = tmp_path / "not-a-directory"
    blocker.write_text("")
    monkeypatch.setenv("XDG_CACHE_HOME", str(blocker))
    assert entry_cache.entries(GROUP) == [("lab_kind", "foo", "lab_kind:KIND")]
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    entry_cache.entries(GROUP)
    (cached,) = (tmp_path / "cache" / "bench" / "kinds").glob("*.txt")
    cached.write_bytes(b"\xff\xfe not text")
    assert entry_cache.entries(GROUP) == [("lab_kind", "foo", "lab_kind:KIND")]


def test_one_cache_file_per_sys_path_and_no_more_than_keep(site, monkeypatch, tmp_path):
    cache = tmp_path / "cache" / "bench" / "kinds"
    for i in range(entry_cache.KEEP + 3):  # python -m bench from as many working directories
        monkeypatch.setattr(sys, "path", [str(tmp_path / f"cwd{i}"), str(site)])
        assert entry_cache.entries(GROUP) == [("lab_kind", "foo", "lab_kind:KIND")]
        assert len(list(cache.glob("*.txt"))) == min(i + 1, entry_cache.KEEP)


def test_a_kind_found_through_the_cache_is_the_one_found_without_it(monkeypatch, tmp_path):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    direct = registry.discover()
    entry_cache.entries(GROUP)  # writes the cache
    cached = registry.discover(entry_cache.entries(GROUP))
    assert list(cached.kinds) == list(direct.kinds) and cached.kinds == direct.kinds and not cached.problems
    assert all(k.package for k in cached.kinds.values())

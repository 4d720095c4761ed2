"""Reliability III (issue 31), outside the web station: run files, catalogues, outputs and inputs
made by someone else (or by a damaged disk), each case of the adversarial pass that failed before.

Cases: S1 (secrets kept out of run files), S7 (links out of the runs directory), S8 (terminal
escapes in run-file texts, also in `bench watch`), S9 (a catalogue URL with ``@`` in its password), D1 (``-o`` onto a
device or FIFO), D2 (truncated files under ``--verify``), D3 (a newer catalogue left untouched), D4
(flipped attribute bits), D5 (kill -9 while a run file is set up), H1 (FIFO inputs), T1 (a file name
that is not UTF-8), T4-T10 (catalogue and CLI edge cases). docs/reliability.md lists them.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from bench.cli import main
from tests.conftest import ROOT, run_cli


def _recorded(runs: Path, *, procedure: str = "hostile", operator: str | None = None, unit: str = "", config_text: str = "name: t\n",
              abort_reason: str = "", events: tuple[str, ...] = (), rows: int = 50) -> Path:
    """A small closed run file written by the project's recorder, with the given texts."""
    import numpy as np

    from bench.record import Column, RunRecorder

    rec = RunRecorder.create(runs, procedure_name=procedure, procedure_text=f"name: {procedure}\n", procedure_path=f"{procedure}.yaml",
                             config_text=config_text, config_path="lab.yaml", mode="sim", software_version="test", operator=operator,
                             identity={"unit_serial": unit} if unit else None)
    key = rec.add_stream("board", [Column("temp", "degC", "f8")], rate_hz=10.0)
    rec.start()
    rec.event("run_start", "runner", f"{procedure}: 1 steps", t_s=0.0)
    for i, message in enumerate(events):
        rec.event("note", "runner", message, t_s=0.1 * i)
    t = np.arange(rows) / 10.0
    rec.append(key, t, temp=20.0 + 0.01 * t)
    rec.tick(t[-1])
    rec.close("aborted" if abort_reason else "completed", abort_reason)
    return rec.path


def _cli(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    capsys.readouterr()
    code = main(list(args))
    out = capsys.readouterr()
    return code, out.out, out.err


# ---- S8, T8: texts of files never act on the terminal ---------------------------------------------
ESCAPES = "\x1b[2J\x1b]52;c;cHduZWQ=\x07\x9b31m\u202e"


def test_terminal_escapes_in_run_file_texts_are_shown_not_acted_on(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    runs = tmp_path / "runs"
    path = _recorded(runs, procedure=f"p{ESCAPES}", operator=f"op{ESCAPES}\nbench: all verified", unit=f"SN{ESCAPES}",
                     abort_reason=f"stop{ESCAPES}", events=(f"note{ESCAPES}",))
    code, out, err = _cli(capsys, "inspect", str(path))
    assert code == 0, err
    for c in "\x1b\x07\x9b\u202e":
        assert c not in out, repr(c)
    assert "op\\x1b[2J\\x1b]52;c;cHduZWQ=\\x07\\x9b31m\\u202e\\nbench: all verified" in out.replace("\n", "")
    assert "\nbench: all verified" not in out  # no forged line
    code, out, err = _cli(capsys, "catalog", "rebuild", str(runs))
    assert code == 0, err
    code, out, err = _cli(capsys, "runs", "--runs-dir", str(runs))
    assert code == 0, err
    assert "\x1b" not in out and "\x9b" not in out and "\\x1b[2J" in out.replace("\n", "")


def test_bench_watch_shows_escapes_and_markup_in_run_file_texts_as_text(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`bench watch` prints the procedure, abort reason, events and file name of someone else's run
    file: escapes as escapes, and rich markup in a file name (``[red]``) as the text it is."""
    path = _recorded(tmp_path / "runs", procedure=f"p{ESCAPES}", abort_reason=f"stop{ESCAPES}", events=(f"note{ESCAPES}",))
    path = path.rename(path.with_name("run[red]x.h5"))
    code, out, err = _cli(capsys, "watch", str(path), "--once")
    assert code == 0, err
    for c in "\x1b\x07\x9b\u202e":
        assert c not in out, repr(c)
    flat = "".join(line.strip("│ ") for line in out.splitlines())
    assert "p\\x1b[2J" in flat and "stop\\x1b[2J" in flat and "note\\x1b[2J" in flat, out
    assert "run[red]x.h5" in out, out


def test_a_line_break_in_a_file_name_cannot_forge_a_line_of_a_message(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    name = tmp_path / "x\nbench: inspected, all verified\x1b[1A.h5"
    name.write_bytes(b"not hdf5")
    code, out, err = _cli(capsys, "inspect", str(name))
    assert code == 2
    assert err.count("\n") == 1 and "\x1b" not in err, err
    assert "x\\nbench: inspected, all verified\\x1b[1A.h5" in err


# ---- T7: a reader that goes away --------------------------------------------------------------------
def test_a_closed_pipe_ends_the_listing_quietly(tmp_path: Path) -> None:
    from bench.catalog.store import open_catalog, resolve_url
    from bench.catalog.schema import ROW_FIELDS

    runs = tmp_path / "runs"
    runs.mkdir()
    rows = [{**{k: "" for k in ROW_FIELDS}, "path": f"/x/{i}.h5", "status": "completed", "started_utc": None, "ended_utc": None,
             "run_time_s": 1.0, "verdict": "passed", "first_failed_check": None, "reason": None, "min_pressure_torr": None,
             "temp_min_degc": None, "temp_max_degc": None} for i in range(300)]
    with open_catalog(resolve_url(None, runs)) as cat:
        cat.insert_new(rows)
    # --json: 180 kB, more than a pipe holds, and the reader leaves after 10 bytes (a write fails);
    # the table: the reader is gone before it starts (its first write, or the flush at exit, fails)
    commands = ((["runs", "--json"], 10), (["runs"], 0))
    procs = [subprocess.Popen([sys.executable, "-m", "bench", *args, "--runs-dir", str(runs)], cwd=ROOT, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE) for args, _n in commands]
    for p, (_args, n) in zip(procs, commands):
        if not n:
            p.stdout.close()
    for p, (args, n) in zip(procs, commands):
        head = p.stdout.read(n) if n else b"-"
        p.stdout.close()
        err = p.stderr.read().decode()
        code = p.wait(timeout=60)
        assert head and err == "", (args, err)
        assert code == 1, args


# ---- catalogue: S7, S9, D3, T1, T4, T5, T6, T9 ----------------------------------------------------------
def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _catalogue(runs: Path) -> Path:
    """An empty catalogue made by bench in ``runs`` (created if needed); its file."""
    from bench.catalog.store import open_catalog, resolve_url

    runs.mkdir(parents=True, exist_ok=True)
    with open_catalog(resolve_url(None, runs)):
        pass
    return runs / "catalog.sqlite"


def test_a_newer_catalogue_is_refused_without_a_byte_changed(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import sqlite3

    runs = tmp_path / "runs"
    runs.mkdir()
    db = runs / "catalog.sqlite"
    con = sqlite3.connect(db)
    con.execute("CREATE TABLE catalog_schema (version INTEGER PRIMARY KEY, applied_utc TIMESTAMP NOT NULL, software_version TEXT NOT NULL)")
    con.execute("INSERT INTO catalog_schema VALUES (99, '2031-01-01 00:00:00', 'bench 9')")
    con.commit()
    con.close()
    assert db.read_bytes()[18:20] == b"\x01\x01"  # rollback journal: what a newer bench might have chosen
    before = _sha(db)
    for args in (["runs", "--runs-dir", str(runs)], ["catalog", "rebuild", str(runs)]):
        code, _out, err = _cli(capsys, *args)
        assert code == 1 and "newer than this bench knows" in err, err
        assert _sha(db) == before, args  # not even the journal mode switched


def test_a_garbage_catalogue_says_to_move_it_aside_and_rebuild_then_works(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    runs = tmp_path / "runs"
    _recorded(runs)
    db = runs / "catalog.sqlite"
    db.write_bytes(b"this is not a database\n" * 100)
    for args in (["runs", "--runs-dir", str(runs)], ["catalog", "rebuild", str(runs)]):
        code, _out, err = _cli(capsys, *args)
        assert code == 1 and f"mv {db} {db}.broken" in err and f"bench catalog rebuild {runs}" in err, err
        assert err.count("\n") == 1
    db.rename(db.with_name("catalog.sqlite.broken"))
    assert _cli(capsys, "catalog", "rebuild", str(runs))[0] == 0
    assert "1 run(s)" in _cli(capsys, "runs", "--runs-dir", str(runs))[1]


def test_a_read_only_catalogue_can_still_be_queried(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    if os.geteuid() != 0:
        pytest.skip("a read-only bind mount needs root")
    runs, ro = tmp_path / "runs", tmp_path / "ro"
    _recorded(runs)
    assert _cli(capsys, "catalog", "rebuild", str(runs))[0] == 0
    ro.mkdir()
    r = subprocess.run(f"mount --bind {runs} {ro} && mount -o remount,ro,bind {ro}", shell=True, capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot make a read-only bind mount: {r.stderr.strip()}")
    try:
        code, out, err = _cli(capsys, "runs", "--runs-dir", str(ro))
        assert code == 0 and "1 run(s)" in out, err
        code, _out, err = _cli(capsys, "catalog", "rebuild", str(ro))
        assert code == 1 and "read-only" in err and "Traceback" not in err, err
    finally:
        subprocess.run(["umount", "-l", str(ro)], capture_output=True)


def test_a_huge_limit_is_bad_input(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    runs = tmp_path / "runs"
    _catalogue(runs)
    code, _out, err = _cli(capsys, "runs", "--runs-dir", str(runs), "--limit", "99999999999999999999")
    assert code == 2 and err.startswith("--limit: must be between 1 and"), err
    assert _cli(capsys, "runs", "--runs-dir", str(runs), "--limit", str(2**63 - 1))[0] == 0


@pytest.mark.parametrize("url, words", [
    ("postgresql://bench:p@ss@127.0.0.1:1/bench", "holds an '@': write it as %40"),
    ("postgresql://bench@127.0.0.1:99999/bench", "port 99999 is not a TCP port"),
    ("postgresql://bench@127.0.0.1:1/bench?sslmode=bogus", "sslmode 'bogus' is not one of"),
])
def test_a_bad_catalogue_url_is_bad_input_and_shows_no_password(tmp_path: Path, capsys: pytest.CaptureFixture[str], url: str,
                                                                words: str) -> None:
    code, _out, err = _cli(capsys, "runs", "--catalog", url)
    assert code == 2 and words in err, err
    assert "p@ss" not in err and "ss@" not in err


def test_a_file_name_that_is_not_utf8_is_listed_and_the_rest_catalogued(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    runs = tmp_path / "runs"
    good = _recorded(runs)
    bad = Path(os.fsdecode(bytes(runs) + b"/bad\xff.h5"))
    bad.write_bytes(good.read_bytes())
    code, out, err = _cli(capsys, "catalog", "rebuild", str(runs))
    assert code == 1 and "catalogued 1 of 2" in out and "bad\\xff.h5: the file name is not UTF-8" in err, out + err
    code, _out, err = _cli(capsys, "report", str(bad), "-o", str(tmp_path / "r.html"))
    assert code == 0, err
    assert "bad\\xff.h5" in (tmp_path / "r.html").read_text(encoding="utf-8")


def test_a_link_out_of_the_runs_directory_is_not_catalogued(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    runs, elsewhere = tmp_path / "runs", tmp_path / "elsewhere"
    _recorded(runs)
    outside = _recorded(elsewhere, procedure="secret_project", unit="SN-OTHER")
    (runs / "innocent.h5").symlink_to(outside)
    (runs / "sub").symlink_to(elsewhere, target_is_directory=True)
    code, out, err = _cli(capsys, "catalog", "rebuild", str(runs), "--recursive")
    assert code == 0 and "catalogued 1 of " in out and "innocent.h5: a link to" in err and "outside" in err, out + err
    assert "secret_project" not in _cli(capsys, "runs", "--runs-dir", str(runs))[1]


def test_a_fleet_skips_links_out_of_its_directory_as_the_catalogue_does(tmp_path: Path) -> None:
    """`bench fleet ... DIR` works on DIR's runs: a link to another directory's run file (or to the
    directory) is skipped with the catalogue's reason, not processed as one of DIR's."""
    from bench.fleet.files import files_in

    runs, elsewhere = tmp_path / "runs", tmp_path / "elsewhere"
    own = _recorded(runs)
    outside = _recorded(elsewhere, procedure="secret_project")
    (runs / "innocent.h5").symlink_to(outside)
    (runs / "sub").symlink_to(elsewhere, target_is_directory=True)
    (runs / "inner").mkdir()
    (runs / "inner" / "same.h5").symlink_to(own)  # a link that stays inside is one of DIR's files
    warned: list[str] = []
    refs = files_in(runs, warn=warned.append)
    assert sorted(r.rel for r in refs) == sorted([own.name, "inner/same.h5"]), refs
    assert any("innocent.h5: a link to" in w for w in warned) and all("outside" in w for w in warned), warned


# ---- S1: no credential in a run file ----------------------------------------------------------------------
SECRET = "Tr0ub4dor-3"


def test_no_credential_is_stored_in_a_run_file(tmp_path: Path) -> None:
    """A dry-run on a lab config naming its catalogue with a password: the file keeps the config
    text with the password masked, and no byte of the file holds the password."""
    import shutil

    shutil.copytree(ROOT / "configs", tmp_path / "configs")
    config = tmp_path / "configs" / "lab.yaml"
    text = (ROOT / "configs" / "sim.yaml").read_text()
    config.write_text(text.replace("instruments:", f"catalog: postgresql://bench:{SECRET}@127.0.0.1:1/bench\ninstruments:", 1))
    proc = tmp_path / "short.yaml"
    proc.write_text("schema: bench-procedure/1\nname: short\ninstruments: [acs_board]\nsteps:\n"
                    "  - power: {instrument: acs_board, on: true}\n  - record: {instrument: acs_board, duration: 2 s}\n")
    r = run_cli("run", str(proc), "--config", str(config), "--sim", "--runs-dir", str(tmp_path / "runs"), cwd=tmp_path)
    assert r.returncode == 0, r.stdout + r.stderr
    (path,) = (tmp_path / "runs").glob("*.h5")
    from bench.record import read_run_summary

    assert f"catalog: postgresql://bench:***@127.0.0.1:1/bench" in read_run_summary(path).config_text
    assert SECRET.encode() not in path.read_bytes()
    assert SECRET not in r.stdout + r.stderr


def test_the_recorder_masks_credentials_in_every_text(tmp_path: Path) -> None:
    from bench.record import read_run_summary

    url = f"postgresql://bench:{SECRET}@labdb/bench"
    path = _recorded(tmp_path, config_text=f"catalog: {url}\n", operator=f"token={SECRET}", unit=f"SN api_key: {SECRET}",
                     abort_reason=f"catalogue {url} failed", events=(f"connecting to {url}", f"Authorization: Bearer {SECRET}"))
    raw = path.read_bytes()
    assert SECRET.encode() not in raw
    s = read_run_summary(path)
    assert "postgresql://bench:***@labdb/bench" in s.config_text and s.abort_reason == "catalogue postgresql://bench:***@labdb/bench failed"
    assert [e.message for e in s.events if e.kind == "note"] == ["connecting to postgresql://bench:***@labdb/bench",
                                                                 "Authorization: Bearer ***"]


# ---- D1: -o only replaces a regular file ----------------------------------------------------------------
def test_output_never_replaces_a_device_or_fifo(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import stat

    run = _recorded(tmp_path / "runs")
    device = tmp_path / "full"  # a private node of /dev/full's device: a failing run must not replace the machine's
    try:
        os.mknod(device, 0o666 | stat.S_IFCHR, os.makedev(1, 7))
    except OSError as exc:
        pytest.skip(f"cannot make a device node here: {exc.strerror}")
    fifo = tmp_path / "out.fifo"
    os.mkfifo(fifo)
    link = tmp_path / "link.html"
    link.symlink_to(tmp_path / "target.html")
    for target, kind in ((device, "a character device"), (fifo, "a FIFO"), (link, "a symbolic link")):
        code, _out, err = _cli(capsys, "report", str(run), "-o", str(target), "--force")
        assert code == 2 and f"{target} is {kind}" in err, err
    assert device.is_char_device() and fifo.is_fifo() and link.is_symlink()
    assert not (tmp_path / "target.html").exists()
    assert _cli(capsys, "report", str(run), "-o", str(tmp_path / "r.html"), "--force")[0] == 0  # a regular file still is


# ---- H1: data inputs that are FIFOs ---------------------------------------------------------------------------
def _main_or_unblock(fifo: Path, args: list[str], timeout_s: float = 20.0) -> tuple[int | None, str]:
    """``bench ARGS`` in a thread of this process; if it is still running after ``timeout_s`` (blocked
    on the FIFO), the FIFO is opened for writing to release it, and the result says None."""
    import contextlib
    import io
    import threading

    out: dict[str, object] = {}
    err = io.StringIO()

    def target() -> None:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            out["code"] = main(args)

    t = threading.Thread(target=target, daemon=True)
    t.start()
    t.join(timeout_s)
    if t.is_alive():
        fd = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)  # a reader is there: this opens, and closing gives it EOF
        os.close(fd)
        t.join(30)
        return None, err.getvalue()
    return out.get("code"), err.getvalue()  # type: ignore[return-value]


def test_a_fifo_as_data_input_is_refused_at_once(tmp_path: Path) -> None:
    for suffix in (".csv", ".h5", ".nc"):
        fifo = tmp_path / f"data{suffix}"
        os.mkfifo(fifo)
        for args in (["diagnose", str(fifo)], ["calibrate", "noise", str(fifo)], ["import", str(fifo), "-o", str(tmp_path / "x.h5")],
                     ["calibrate", "noise", str(fifo), "--map", "gyro=angular_velocity:rad/s"]):
            code, err = _main_or_unblock(fifo, args)  # before: blocked for ever on open()
            assert code == 2 and "not a regular file" in err.strip().splitlines()[-1], (args, code, err)


# ---- T10, D2, D4: damaged files ------------------------------------------------------------------------------
def test_a_link_to_nothing_inside_a_run_file_is_named(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import h5py

    path = _recorded(tmp_path)
    with h5py.File(path, "r+") as f:
        f["instruments"]["board"] = h5py.SoftLink("/nowhere")
    for args in (["inspect", str(path)], ["report", str(path), "-o", str(tmp_path / "r.html")], ["catalog", "rebuild", str(tmp_path)]):
        code, _out, err = _cli(capsys, *args)
        assert code in (1, 2) and "/instruments/board is a link to /nowhere, which does not exist" in err, (args, err)
        assert "NoneType" not in err
    code, out, _err = _cli(capsys, "inspect", str(path), "--verify")  # the file's structure changed since it was written
    assert code == 1 and "CHANGED" in out


@pytest.mark.parametrize("cut", [1, 100, 5000])
def test_verify_fails_a_truncated_file(tmp_path: Path, capsys: pytest.CaptureFixture[str], cut: int) -> None:
    path = _recorded(tmp_path, rows=3000)
    code, out, _err = _cli(capsys, "inspect", str(path), "--verify")
    assert code == 0 and "verified" in out
    data = path.read_bytes()
    path.write_bytes(data[:-cut])
    code, out, err = _cli(capsys, "inspect", str(path), "--verify")
    assert code in (1, 2) and "verified:" not in out, out + err
    assert "truncated" in out + err


def _flip_attribute(path: Path, name: str) -> str:
    """Flip one bit of the stored value of root attribute ``name`` in ``path`` (the occurrence HDF5
    reads back changed, without an error); the value read after."""
    import h5py

    with h5py.File(path, "r") as f:
        value = str(f.attrs[name])
    data = path.read_bytes()
    start = 0
    while True:
        pos = data.find(value.encode(), start)
        assert pos >= 0, f"no occurrence of {value!r} changes attribute {name}"
        damaged = bytearray(data)
        damaged[pos + 1] ^= 0x04
        path.write_bytes(bytes(damaged))
        try:
            with h5py.File(path, "r") as f:
                now = str(f.attrs[name])
        except Exception:  # noqa: BLE001 - that occurrence was metadata HDF5 checks
            now = value
        if now != value:
            return now
        path.write_bytes(data)
        start = pos + 1


@pytest.mark.parametrize("name", ["status", "procedure_name", "started_utc"])
def test_verify_sees_a_bit_flipped_in_an_attribute(tmp_path: Path, capsys: pytest.CaptureFixture[str], name: str) -> None:
    path = _recorded(tmp_path, procedure="attr_probe")
    assert _cli(capsys, "inspect", str(path), "--verify")[0] == 0
    changed = _flip_attribute(path, name)
    code, out, err = _cli(capsys, "inspect", str(path), "--verify")
    assert code == 1 and "attributes or texts changed" in out and "attributes and texts" in out and "CHANGED" in out, (changed, out, err)


def test_verify_says_the_attributes_of_an_older_file_are_not_checked(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import h5py

    path = _recorded(tmp_path)
    with h5py.File(path, "r+") as f:
        del f.attrs["attrs_sha256"]  # as written before digests
    code, out, _err = _cli(capsys, "inspect", str(path), "--verify")
    assert code == 0 and "not checked" in out and "the attributes (no digest" in out and "/config/text" in out, out


# ---- D5: kill -9 while the run file is set up -------------------------------------------------------------
SETUP_WRITER = """
import sys, time
from pathlib import Path
from bench.record import Column, RunRecorder
rec = RunRecorder.create(Path(sys.argv[1]), procedure_name="setup", procedure_text="name: setup\\n", procedure_path="setup.yaml",
                         config_text="name: lab\\n", config_path="lab.yaml", mode="sim", software_version="test")
for i in range(40):  # the setup of a run: instruments identified, streams declared (before SWMR mode)
    rec.add_instrument(f"inst{i}", {"model": "x" * 200})
    rec.add_stream(f"inst{i}", [Column("v", "V", "f8")])
    time.sleep(0.01)
time.sleep(60)
"""


def _kill_when_named(jobs: list[tuple[list[str], Path]]) -> list[Path]:
    """Start each ``(argv, runs)`` at once and SIGKILL each the moment a ``*.h5`` appears in its
    ``runs``; those files."""
    procs = [(subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL), runs) for argv, runs in jobs]
    found: dict[int, Path] = {}
    deadline = time.monotonic() + 60
    while len(found) < len(procs) and time.monotonic() < deadline:
        for i, (p, runs) in enumerate(procs):
            if i not in found:
                files = list(runs.glob("*.h5")) if runs.exists() else []
                if files or p.poll() is not None:
                    p.kill()
                    found[i] = files[0] if files else Path()
    for p, _runs in procs:
        p.kill()
        p.wait(timeout=10)
    assert all(f != Path() for f in found.values()) and len(found) == len(procs), "a run file did not appear"
    return list(found.values())


def test_a_run_file_killed_while_set_up_can_be_read(tmp_path: Path) -> None:
    """kill -9 the moment the run file's name appears, during the set-up before SWMR mode (before: 5
    of 5 such files were unopenable, "marked open for writing outside SWMR mode"): the file reads,
    as crashed. Four recorders killed so, and one `bench run`."""
    from bench.record import read_run_summary

    script = tmp_path / "setup_writer.py"
    script.write_text(SETUP_WRITER)
    proc = tmp_path / "short.yaml"
    proc.write_text("schema: bench-procedure/1\nname: short\ninstruments: [acs_board]\nsteps:\n"
                    "  - power: {instrument: acs_board, on: true}\n  - record: {instrument: acs_board, duration: 2 s}\n")
    jobs = [([sys.executable, str(script), str(tmp_path / f"runs{n}")], tmp_path / f"runs{n}") for n in range(4)]
    jobs.append(([sys.executable, "-m", "bench", "run", str(proc), "--config", str(ROOT / "configs" / "sim.yaml"), "--sim",
                  "--runs-dir", str(tmp_path / "runs_cli")], tmp_path / "runs_cli"))
    for path in _kill_when_named(jobs):
        s = read_run_summary(path, stale_after_s=0.0)  # readable, whatever moment the kill hit
        assert s.status in ("crashed", "completed"), (path, s.status)

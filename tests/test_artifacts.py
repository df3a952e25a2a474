"""Artifact store: atomic writes, manifests, verification and code versions."""

import json
import os
import shutil

import pytest

from tasks.artifacts import (atomic_write_json, atomic_write_text, code_version, read_manifest, recorded_folder,
                             sha256_file, unit_key, valid_manifest, verify, write_manifest)
from tasks.specialist_index import rebase_entry


def _unit(tmp_path, text="hello"):
    folder = tmp_path / "stages" / "demo" / "k1"
    out = atomic_write_text(folder / "out.txt", text)
    return write_manifest(stage="demo", unit="u", key="k1", folder=folder, files={"out": out}, code="c",
                          metrics={"n": 3})


def test_atomic_write_leaves_no_temp_files(tmp_path):
    atomic_write_json(tmp_path / "a.json", {"x": 1})
    assert json.loads((tmp_path / "a.json").read_text()) == {"x": 1}
    assert os.listdir(tmp_path) == ["a.json"]


def test_manifest_roundtrip_and_hashes(tmp_path):
    manifest = _unit(tmp_path)
    assert manifest.files["out"].sha256 == sha256_file(manifest.path("out"))
    again = read_manifest(manifest.folder)
    assert again == manifest and again.hash == manifest.hash
    assert valid_manifest(manifest.folder) == manifest


def test_missing_or_altered_file_invalidates_manifest(tmp_path):
    manifest = _unit(tmp_path)
    manifest.path("out").write_text("hellO")
    assert verify(manifest) and "altered" in verify(manifest)[0]
    assert valid_manifest(manifest.folder) is None
    manifest.path("out").unlink()
    assert "missing" in verify(manifest)[0]


def test_a_moved_unit_verifies_and_serves_the_files_where_it_is_now(tmp_path):
    manifest = _unit(tmp_path / "a")
    shutil.copytree(tmp_path / "a", tmp_path / "b")
    (tmp_path / "a" / "stages" / "demo" / "k1" / "out.txt").write_text("changed at the old place")
    moved = read_manifest(tmp_path / "b" / "stages" / "demo" / "k1")
    assert moved.folder == str(tmp_path / "b" / "stages" / "demo" / "k1") and moved.hash == manifest.hash
    assert moved.path("out").read_text() == "hello" and valid_manifest(moved.folder) == moved
    assert recorded_folder(moved.folder) == manifest.folder  # what it was written with, until rewritten
    shutil.rmtree(tmp_path / "a")
    assert valid_manifest(tmp_path / "b" / "stages" / "demo" / "k1") == moved


def test_a_specialist_index_row_follows_its_stage_folder(tmp_path):
    row = {"unit": "bin-0", "folder": "/old/runs/stages/specialists/k1", "policy": "/old/runs/stages/specialists/k1/policy.pt",
           "records": "/old/runs/stages/specialists/k1/sub/records.json", "metrics": {"records": 3.0}}
    moved = rebase_entry(row, tmp_path / "specialists")
    assert moved == {**row, "folder": str(tmp_path / "specialists" / "k1"),
                     "policy": str(tmp_path / "specialists" / "k1" / "policy.pt"),
                     "records": str(tmp_path / "specialists" / "k1" / "sub" / "records.json")}
    assert rebase_entry(moved, tmp_path / "specialists") == moved


def test_corrupt_manifest_reads_as_not_done(tmp_path):
    manifest = _unit(tmp_path)
    (tmp_path / "stages" / "demo" / "k1" / "manifest.json").write_text("{not json")
    assert read_manifest(manifest.folder) is None and valid_manifest(manifest.folder) is None


def test_unit_key_depends_on_every_input():
    base = dict(stage="s", unit="u", section_digest="d", upstream={"a": "1"}, code="c")
    key = unit_key(**base)
    for field, value in [("stage", "t"), ("unit", "v"), ("section_digest", "e"), ("upstream", {"a": "2"}),
                         ("code", "x")]:
        assert unit_key(**{**base, field: value}) != key


def test_code_version_changes_when_a_source_file_changes(tmp_path):
    pkg = tmp_path / "components" / "thing"
    pkg.mkdir(parents=True)
    (pkg / "a.py").write_text("x = 1\n")
    before = code_version("components/thing", root=tmp_path)
    (pkg / "a.py").write_text("x = 2\n")
    os.utime(pkg / "a.py", ns=(10**9, 10**9))  # another mtime whatever the clock's tick: digests are memoised by it
    assert code_version("components/thing", root=tmp_path) != before


def test_code_version_ignores_comments_docstrings_and_field_descriptions_but_not_code_or_assets(tmp_path):
    """An edit of the documentation alone keeps every finished stage; any edit of what runs, or of an asset file,
    keys new units."""
    pkg = tmp_path / "components" / "thing"
    pkg.mkdir(parents=True)
    base = ('"""Module docstring."""\n\nfrom pydantic import BaseModel, Field\n\n\n'
            'class Config(BaseModel):\n    """A config."""\n\n'
            '    size: float = Field(1.0, gt=0, description="Size (m).")  # a comment\n'
            '    """Attribute docstring."""\n\n\n'
            'def area(c: Config) -> float:\n    """Area."""\n    label = "é"; """after a non-ASCII literal"""\n'
            '    return c.size ** 2  # square\n')
    (pkg / "data.yaml").write_text("a: 1\n")

    writes = iter(range(1, 100))

    def version(text: str) -> str:  # each write its own mtime: digests are memoised by path, mtime and size
        (pkg / "a.py").write_text(text)
        stamp = next(writes) * 10**9
        os.utime(pkg / "a.py", ns=(stamp, stamp))
        return code_version("components/thing", root=tmp_path)

    before = version(base)
    documented = (base.replace('"""A config."""', '"""A config,\n    documented at length."""')
                  .replace('description="Size (m)."', 'description="Size of the thing (m); "\n        "more words."')
                  .replace("# a comment", "# another comment").replace('"""Area."""', "# Area.")
                  .replace('"""after a non-ASCII literal"""', '"""changed"""') + "\n\n# trailing comment\n")
    assert version(documented) == before
    assert version(base.replace("c.size ** 2", "c.size ** 3")) != before
    assert version(base.replace('"é"', '"e"')) != before  # a string that is not documentation is code
    assert version(base.replace("gt=0", "ge=0")) != before
    version(base)
    (pkg / "data.yaml").write_text("a: 2\n")
    os.utime(pkg / "data.yaml", ns=(10**9, 10**9))
    assert code_version("components/thing", root=tmp_path) != before


def _hold_lock_in_another_process(path, ready, release):
    """A child process holding :func:`tasks.artifacts.file_lock` at ``path`` until the file ``release`` exists (at
    most 120 s), returned once it holds it (it touches ``ready`` then). The test decides when the lock is let go, so
    no assertion depends on how fast a loaded machine schedules either process."""
    import subprocess
    import sys
    import time

    holder = subprocess.Popen([sys.executable, "-c", (
        "import pathlib, time\n"
        "from tasks.artifacts import file_lock\n"
        f"with file_lock(pathlib.Path({str(path)!r})):\n"
        f"    pathlib.Path({str(ready)!r}).touch()\n"
        "    deadline = time.monotonic() + 120\n"
        f"    while not pathlib.Path({str(release)!r}).exists() and time.monotonic() < deadline:\n"
        "        time.sleep(0.02)\n")])
    while not ready.exists():
        assert holder.poll() is None
        time.sleep(0.05)
    return holder


def test_a_file_lock_held_by_another_process_names_it_and_waits_for_it(tmp_path):
    import threading
    import time

    from tasks.artifacts import file_lock

    path, release = tmp_path / "locks" / "unit.lock", tmp_path / "release"
    holder = _hold_lock_in_another_process(path, tmp_path / "ready", release)
    try:
        waited, start = [], time.monotonic()

        def on_wait(line: str) -> None:  # the holder lets go 0.6 s after the wait began
            waited.append(line)
            threading.Timer(0.6, release.touch).start()

        with file_lock(path, on_wait=on_wait):
            assert time.monotonic() - start > 0.5  # it blocked until the holder's block ended
        assert len(waited) == 1 and waited[0].startswith(f"pid {holder.pid} (")
    finally:
        release.touch()
        holder.wait(timeout=30)
    calls = []
    with file_lock(path, on_wait=calls.append):  # free: no wait
        pass
    assert calls == []


def test_a_unit_whose_other_invocation_ended_unfinished_says_it_computes_it_here(tmp_path, caplog):
    """Waiting for another invocation's unit, then finding it unfinished (that invocation was killed): one line says
    the unit is computed here, so the waiting line is not the last word on it."""
    import logging

    from tasks.artifacts import lock_path
    from tasks.units import UnitOutput, make_spec, run_unit

    spec = make_spec(stage="demo", unit="u", section_digest="s", upstream={}, code="c", workdir=tmp_path)
    release = tmp_path / "release"

    class ReleaseWhenWaiting(logging.Handler):  # the holder ends (unfinished) once this invocation waits for it
        def emit(self, record):
            if "waiting for it" in record.getMessage():
                release.touch()

    holder = _hold_lock_in_another_process(lock_path(tmp_path, spec.key), tmp_path / "ready", release)
    handler = ReleaseWhenWaiting()
    logging.getLogger("multigrasp").addHandler(handler)
    try:
        with caplog.at_level(logging.WARNING, logger="multigrasp"):
            out = run_unit(spec, lambda folder: UnitOutput(files={}, metrics={"x": 1}))
    finally:
        logging.getLogger("multigrasp").removeHandler(handler)
        release.touch()
        holder.wait(timeout=30)
    assert out.metrics == {"x": 1}
    lines = [r.getMessage() for r in caplog.records]
    assert any("waiting for it" in line for line in lines)
    assert lines[-1].endswith("the other invocation ended without finishing it; computing it here")


def test_lock_holder_names_the_holder_without_taking_the_lock(tmp_path, monkeypatch):
    """``status`` asks who holds each unit's lock; on Linux it reads /proc/locks, so a unit starting at that
    instant never finds the lock taken by ``status`` (and logs no spurious waiting line)."""
    import fcntl

    import tasks.artifacts
    from tasks.artifacts import lock_holder

    if not tasks.artifacts.PROC_LOCKS.exists():
        pytest.skip("no /proc/locks: lock_holder tries the lock instead")
    path = tmp_path / "unit.lock"
    holder = _hold_lock_in_another_process(path, tmp_path / "ready", tmp_path / "never")
    try:
        real_flock = fcntl.flock
        monkeypatch.setattr(fcntl, "flock", lambda *a: pytest.fail("lock_holder took the lock"))
        assert lock_holder(path).startswith(f"pid {holder.pid} (")
        monkeypatch.setattr(fcntl, "flock", real_flock)
    finally:
        holder.kill()
        holder.wait(timeout=30)
    monkeypatch.setattr(fcntl, "flock", lambda *a: pytest.fail("lock_holder took the lock"))
    assert lock_holder(path) is None  # its holder has ended: nothing listed
    assert lock_holder(tmp_path / "nothing.lock") is None

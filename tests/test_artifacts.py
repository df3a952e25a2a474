"""Artifact store: atomic writes, manifests, verification and code versions."""

import json
import os

from tasks.artifacts import (atomic_write_json, atomic_write_text, code_version, read_manifest, sha256_file,
                             unit_key, valid_manifest, verify, write_manifest)


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
    assert code_version("components/thing", root=tmp_path) != before

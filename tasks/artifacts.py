"""Artifacts on disk: atomic writes, content hashes, stage folders and manifests.

Layout of a work directory (default ``./runs``)::

    <workdir>/
      stages/<stage>/<key>/        one folder per unit of work, content-addressed by its cache key
          manifest.json            written last: its presence marks the unit as finished
          <files…>                 the unit's outputs, each listed in the manifest with its sha256
      cache/                       component caches (mesh SDF grids, convex decompositions, URDF)
      prefect/results/             Prefect result records (one small manifest per cache key)
      results/                     human-facing reports (JSON + markdown tables)
      locks/                       one lock file per unit being computed (two invocations compute a unit once), the
                                   work dir's own lock (held shared by every invocation, exclusively by prune)
      mlflow.db, mlartifacts/      the embedded MLflow store

A unit's cache key is ``sha256(stage, config-section digest, upstream manifest hashes,
component code version)``.  A manifest is *valid* only if every file it lists exists and
still has the recorded sha256; anything else (missing file, edited file, unreadable
manifest) makes the unit count as not done, so it is recomputed instead of trusted.
"""

from __future__ import annotations

import ast
import contextlib
import fcntl
import functools
import io
import json
import os
import sys
import tempfile
import time
import tokenize
from collections.abc import Callable, Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from components.fileio import atomic_write_bytes, atomic_write_text, sha256_bytes, sha256_file  # noqa: F401

REPO_ROOT = Path(__file__).resolve().parents[1]
"""The project root (holds ``components/``, ``assets/``); used for code versions."""

MANIFEST_NAME = "manifest.json"


LOCKS_DIR = "locks"


def lock_path(workdir: Path, name: str) -> Path:
    """``<workdir>/locks/<name>.lock``: the lock file of one unit (its key) or of the work dir's MLflow store."""
    return Path(workdir) / LOCKS_DIR / f"{name}.lock"


@contextlib.contextmanager
def file_lock(path: Path, on_wait: Callable[[str], None] | None = None) -> Iterator[None]:
    """An exclusive advisory lock (``flock``) on ``path`` across processes, for the ``with`` block.

    Two invocations on one work dir (a second terminal, two configs run side by side) use it so that a unit is
    computed once: the second waits for the first and then finds the unit finished.  ``on_wait(holder)`` is called
    once if the lock is held elsewhere (``holder``: what the holder wrote, its pid and command line), before
    blocking.  The kernel releases the lock when its process ends, ``kill -9`` included, so no stale lock is left."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a+") as handle:
        def waiting() -> None:
            if on_wait is not None:
                handle.seek(0)
                on_wait(handle.read().strip() or "another process")

        _flock(handle, fcntl.LOCK_EX, waiting)
        try:
            handle.seek(0)
            handle.truncate()
            handle.write(_holder_line())
            handle.flush()
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def _flock(handle, mode: int, on_wait: Callable[[], None] | None) -> None:
    """``flock(handle, mode)``; if another process holds it, call ``on_wait()`` once, then block until it is free."""
    try:
        fcntl.flock(handle, mode | fcntl.LOCK_NB)
    except BlockingIOError:
        if on_wait is not None:
            on_wait()
        fcntl.flock(handle, mode)


def _holder_line() -> str:
    """What a lock holder writes about itself: its pid and command line."""
    return f"pid {os.getpid()} ({' '.join(sys.argv)[:200]})"


PROC_LOCKS = Path("/proc/locks")
"""Linux's table of the file locks held now: read to see a lock without taking it (:func:`lock_holder`)."""


def _flock_listed(path: Path) -> bool | None:
    """Whether :data:`PROC_LOCKS` lists a ``flock`` on ``path``'s inode (None where there is no such table)."""
    try:
        stat = path.stat()
        table = PROC_LOCKS.read_text()
    except OSError:
        return None
    inode = f"{os.major(stat.st_dev):02x}:{os.minor(stat.st_dev):02x}:{stat.st_ino}"
    return any(len(fields) > 5 and fields[1] == "FLOCK" and fields[5] == inode
               for fields in (line.split() for line in table.splitlines()))


def lock_holder(path: Path) -> str | None:
    """What holds the lock at ``path`` now (its pid and command line, as :func:`file_lock` wrote them), or None
    when nothing does (no such file, or a lock left by a process that has ended).  On Linux it reads
    :data:`PROC_LOCKS` and never takes the lock, so a unit that starts at that instant does not wait for ``status``
    (until the fiftieth session it took the lock for an instant, and such a unit logged a spurious waiting line);
    elsewhere it tries the lock without waiting."""
    if not path.exists():
        return None
    with open(path) as handle:
        listed = _flock_listed(path)
        if listed is not None:
            return (handle.read().strip() or "another process") if listed else None
        try:
            fcntl.flock(handle, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return handle.read().strip() or "another process"
        fcntl.flock(handle, fcntl.LOCK_UN)
    return None


WORKDIR_LOCK = "workdir"
"""Name of the work dir's own lock: shared by every invocation that reads or writes units, exclusive for prune."""

INVOCATIONS_DIR = "invocations"
"""``<workdir>/locks/invocations/<pid>``: one file per invocation using the work dir (what it runs), to name it."""


def _invocation_file(workdir: Path) -> Path:
    return Path(workdir) / LOCKS_DIR / INVOCATIONS_DIR / str(os.getpid())


@contextlib.contextmanager
def workdir_in_use(workdir: Path, on_wait: Callable[[], None] | None = None, create: bool = True) -> Iterator[None]:
    """Hold the work dir's lock *shared* for the ``with`` block: any number of invocations (``run``, ``evaluate``,
    ``generate``) use a work dir together, while ``prune`` (:func:`workdir_exclusive`) waits for none of them and
    deletes nothing under a running one.  ``on_wait()`` is called once if a prune holds it now, before blocking.
    Without ``create``, a work dir that does not exist is left so (the command will say what is missing)."""
    if not create and not Path(workdir).is_dir():
        yield
        return
    path = lock_path(workdir, WORKDIR_LOCK)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a+") as handle:
        _flock(handle, fcntl.LOCK_SH, on_wait)
        mine = _invocation_file(workdir)
        try:
            atomic_write_text(mine, _holder_line())
            yield
        finally:
            mine.unlink(missing_ok=True)
            fcntl.flock(handle, fcntl.LOCK_UN)


@contextlib.contextmanager
def workdir_exclusive(workdir: Path) -> Iterator[list[str] | None]:
    """Try to hold the work dir's lock *exclusively* for the ``with`` block, without waiting.  Yields None when it
    holds it, or else the invocations using the work dir now (what :func:`workdir_in_use` recorded; files left by
    processes that have ended are removed)."""
    path = lock_path(workdir, WORKDIR_LOCK)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a+") as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            yield _live_invocations(workdir) or ["another process"]
            return
        try:
            yield None
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def _live_invocations(workdir: Path) -> list[str]:
    folder = Path(workdir) / LOCKS_DIR / INVOCATIONS_DIR
    found = []
    for entry in sorted(folder.glob("*")) if folder.is_dir() else []:
        try:
            os.kill(int(entry.name), 0)
        except ProcessLookupError:
            entry.unlink(missing_ok=True)
            continue
        except (ValueError, PermissionError):
            pass
        try:
            found.append(entry.read_text().strip())
        except OSError:
            continue
    return found


# --------------------------------------------------------------------------- hashing


def canonical_json(obj: Any) -> str:
    """Deterministic JSON (sorted keys, no whitespace) used for every digest."""
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), default=str)


def digest(obj: Any) -> str:
    """sha256 of an object's canonical JSON."""
    return sha256_bytes(canonical_json(obj).encode())


#: keyword arguments whose string value documents a field or an option and never changes what code computes
#: (pydantic's ``Field(description=...)``); left out of :func:`python_code_text`.
DOC_KEYWORDS = frozenset({"description"})


def _is_doc_string(node: ast.AST) -> bool:
    """A string literal, or a concatenation of them (``"a" "b"`` is one literal; ``"a" + "b"`` is not)."""
    if isinstance(node, ast.Constant):
        return isinstance(node.value, str)
    return isinstance(node, ast.BinOp) and isinstance(node.op, ast.Add) and _is_doc_string(node.left) \
        and _is_doc_string(node.right)


def python_code_text(source: str) -> str:
    """``source`` without what only documents it: comments, docstrings (every string literal that stands alone as a
    statement: module, class and function docstrings and the attribute docstrings under fields) and the string
    values of :data:`DOC_KEYWORDS` arguments, with blank lines and trailing spaces dropped.  Works on the text (the
    spans :mod:`ast` and :mod:`tokenize` locate), so the result does not depend on the Python version.  A file that
    does not parse is returned whole."""
    try:
        tree = ast.parse(source)
        comments = [tok for tok in tokenize.generate_tokens(io.StringIO(source).readline)
                    if tok.type == tokenize.COMMENT]
    except (SyntaxError, tokenize.TokenError, ValueError):
        return source
    lines = source.splitlines(keepends=True)
    starts = [0]
    for line in lines:
        starts.append(starts[-1] + len(line))

    def offset(lineno: int, byte_col: int) -> int:  # ast columns count UTF-8 bytes
        line = lines[lineno - 1]
        return starts[lineno - 1] + len(line.encode()[:byte_col].decode(errors="ignore"))

    spans = [(starts[t.start[0] - 1] + t.start[1], starts[t.end[0] - 1] + t.end[1]) for t in comments]
    for node in ast.walk(tree):
        doc = None
        if isinstance(node, ast.Expr) and _is_doc_string(node.value):
            doc = node
        elif isinstance(node, ast.keyword) and node.arg in DOC_KEYWORDS and _is_doc_string(node.value):
            doc = node.value
        if doc is not None:
            spans.append((offset(doc.lineno, doc.col_offset), offset(doc.end_lineno, doc.end_col_offset)))
    kept, at = [], 0
    for start, end in sorted(spans):
        if start >= at:
            kept.append(source[at:start])
            at = end
        else:
            at = max(at, end)
    kept.append(source[at:])
    return "\n".join(line.rstrip() for line in "".join(kept).splitlines() if line.strip()) + "\n"


@functools.lru_cache(maxsize=4096)
def _file_code_digest(path: str, mtime_ns: int, size: int) -> str:
    """sha256 of a project file as :func:`code_version` counts it (memoised by path, mtime and size)."""
    if path.endswith(".py"):
        return sha256_bytes(python_code_text(Path(path).read_text(encoding="utf-8")).encode())
    return sha256_file(Path(path))


def code_version(*relative_dirs: str, root: Path = REPO_ROOT) -> str:
    """Digest of every source/asset file under the given project folders.

    Prefect's ``TASK_SOURCE`` hashes only a task's own body, so an edit in
    ``components/`` would not invalidate a cached result.  Hashing the component
    package (and its assets) makes any code change produce a new cache key.  Python files count without their
    comments, docstrings and field descriptions (:func:`python_code_text`): an edit of the documentation alone
    keeps every finished stage (until the fiftieth session it recomputed them all).  Asset files count byte for byte.
    """
    entries: list[tuple[str, str]] = []
    for rel in sorted(relative_dirs):
        base = root / rel
        files = [base] if base.is_file() else sorted(p for p in base.rglob("*") if p.is_file())
        for path in files:
            if "__pycache__" in path.parts or path.suffix in {".pyc", ".pyo"}:
                continue
            stat = path.stat()
            entries.append((str(path.relative_to(root)), _file_code_digest(str(path), stat.st_mtime_ns, stat.st_size)))
    return digest(["python code without its documentation", entries])[:16]


# --------------------------------------------------------------------------- atomic writes


def atomic_write_json(path: Path, obj: Any) -> Path:
    """Atomically write pretty JSON."""
    return atomic_write_text(path, json.dumps(obj, indent=2, sort_keys=True, default=str) + "\n")


def atomic_write_with(path: Path, writer) -> Path:
    """Atomically create ``path`` with a writer callback ``writer(tmp_path)``.

    For libraries that write files themselves (PNG via Pillow, Parquet via pyarrow,
    ``torch.save``): they write to a temp path, which is then renamed into place.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    try:
        writer(Path(tmp))
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


# --------------------------------------------------------------------------- manifests


class FileEntry(BaseModel):
    """One output file of a unit of work."""

    model_config = ConfigDict(frozen=True)
    path: str = Field(description="Path relative to the unit's folder.")
    sha256: str = Field(description="sha256 of the file's bytes when it was written.")
    bytes: int = Field(description="File size in bytes.")


class Manifest(BaseModel):
    """What a unit of work produced: the small object tasks pass to each other."""

    model_config = ConfigDict(frozen=True)
    stage: str = Field(description="Stage name, e.g. 'scenes'.")
    unit: str = Field(description="Unit within the stage, e.g. 'shard-003' or 'stage'.")
    key: str = Field(description="Cache key of the unit (folder name).")
    folder: str = Field(description="Absolute path of the unit's folder: where it was written, and after read_manifest the folder it was read from (a moved work dir).")
    files: dict[str, FileEntry] = Field(default_factory=dict, description="Outputs by logical name.")
    metrics: dict[str, float] = Field(default_factory=dict, description="Scalar results of the unit.")
    meta: dict[str, Any] = Field(default_factory=dict, description="Small JSON-able facts (counts, names).")
    upstream: dict[str, str] = Field(default_factory=dict, description="Upstream manifest hashes by name.")
    code_version: str = Field(description="Digest of the component code that produced it.")
    producer_run_id: str | None = Field(default=None, description="MLflow run id that produced it.")
    created_unix: float = Field(description="Creation time (seconds since the epoch).")
    seconds: float = Field(default=0.0, description="Wall time the unit took to compute.")

    def path(self, name: str) -> Path:
        """Absolute path of output ``name``."""
        return Path(self.folder) / self.files[name].path

    @property
    def hash(self) -> str:
        """Content hash: changes whenever any output file or metric changes."""
        return digest({"key": self.key, "files": {k: v.sha256 for k, v in self.files.items()},
                       "metrics": self.metrics})[:20]


def unit_key(stage: str, unit: str, section_digest: str, upstream: Mapping[str, str], code: str) -> str:
    """Cache key of a unit: stage + unit + config digest + upstream hashes + code version."""
    return digest({"stage": stage, "unit": unit, "config": section_digest,
                   "upstream": dict(sorted(upstream.items())), "code": code})[:20]


def unit_folder(workdir: Path, stage: str, key: str) -> Path:
    """Folder of a unit: ``<workdir>/stages/<stage>/<key>``."""
    return Path(workdir) / "stages" / stage / key


def write_manifest(
    *,
    stage: str,
    unit: str,
    key: str,
    folder: Path,
    files: Mapping[str, Path],
    code: str,
    metrics: Mapping[str, float] | None = None,
    meta: Mapping[str, Any] | None = None,
    upstream: Mapping[str, str] | None = None,
    producer_run_id: str | None = None,
    seconds: float = 0.0,
) -> Manifest:
    """Hash the unit's output files and write ``manifest.json`` last (atomically)."""
    folder = Path(folder)
    entries = {}
    for name, path in files.items():
        path = Path(path)
        entries[name] = FileEntry(path=str(path.relative_to(folder)), sha256=sha256_file(path),
                                  bytes=path.stat().st_size)
    manifest = Manifest(stage=stage, unit=unit, key=key, folder=str(folder), files=entries,
                        metrics={k: float(v) for k, v in (metrics or {}).items()},
                        meta=dict(meta or {}), upstream=dict(upstream or {}), code_version=code,
                        producer_run_id=producer_run_id, created_unix=time.time(), seconds=seconds)
    atomic_write_text(folder / MANIFEST_NAME, manifest.model_dump_json(indent=2) + "\n")
    return manifest


def read_manifest(folder: Path) -> Manifest | None:
    """The manifest in ``folder``, or None if it is absent or unreadable (corrupt = not done).

    Its ``folder`` is the one it was read from, whatever folder it recorded when it was written: a work dir that was
    moved or copied (``mv runs runs-old``, rsync from a cluster to a laptop) then verifies and serves the files it
    holds, never those left at the old place (see :func:`recorded_folder`)."""
    path = Path(folder) / MANIFEST_NAME
    if not path.is_file():
        return None
    try:
        manifest = Manifest.model_validate_json(path.read_text())
    except (ValueError, OSError):
        return None
    here = str(Path(folder).absolute())
    return manifest if manifest.folder == here else manifest.model_copy(update={"folder": here})


def recorded_folder(folder: Path) -> str | None:
    """The folder that the manifest in ``folder`` recorded when it was written (None if there is no readable
    manifest).  It differs from ``folder`` after the work dir was moved or copied."""
    path = Path(folder) / MANIFEST_NAME
    try:
        return str(json.loads(path.read_text())["folder"])
    except (ValueError, OSError, KeyError, TypeError):
        return None


def verify(manifest: Manifest) -> list[str]:
    """Problems with a manifest's files (empty list = valid): missing or altered outputs."""
    problems = []
    for name, entry in manifest.files.items():
        path = Path(manifest.folder) / entry.path
        if not path.is_file():
            problems.append(f"{name}: missing {path}")
        elif path.stat().st_size != entry.bytes or sha256_file(path) != entry.sha256:
            problems.append(f"{name}: altered {path}")
    return problems


def valid_manifest(folder: Path) -> Manifest | None:
    """The manifest in ``folder`` if it exists and all its files verify, else None."""
    manifest = read_manifest(folder)
    if manifest is None or verify(manifest):
        return None
    return manifest


def upstream_hashes(manifests: Mapping[str, Manifest] | Iterable[tuple[str, Manifest]]) -> dict[str, str]:
    """``{name: manifest.hash}`` for a set of upstream manifests (part of a downstream key)."""
    items = manifests.items() if isinstance(manifests, Mapping) else manifests
    return {name: m.hash for name, m in items}

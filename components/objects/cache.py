"""Verified on-disk caches for derived geometry (SDF grids, stable poses, convex decompositions).

Every file is written atomically (temp file + ``os.replace``) together with the cache key
it was built for and a sha256 of its content. A file that cannot be read, was built for
another key, or whose hash differs is reported as missing, so the caller rebuilds it
(a corrupt cache never crashes a run and is never trusted).
"""

from __future__ import annotations

import hashlib
import json
import logging
from pathlib import Path

import numpy as np

from components.fileio import atomic_write_bytes, sha256_bytes  # noqa: E402,F401  (re-exported)

log = logging.getLogger(__name__)


def _arrays_digest(arrays: dict[str, np.ndarray]) -> str:
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(name.encode())
        h.update(str(a.dtype).encode())
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def write_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (see :mod:`components.fileio`)."""
    atomic_write_bytes(path, data)


def save_arrays(path: Path, key: str, arrays: dict[str, np.ndarray]) -> None:
    """Store ``arrays`` as ``.npz`` with ``key`` and a sha256 over all arrays."""
    import io

    buf = io.BytesIO()
    np.savez(buf, __key__=np.array(key), __digest__=np.array(_arrays_digest(arrays)), **arrays)
    write_atomic(path, buf.getvalue())


def load_arrays(path: Path, key: str) -> dict[str, np.ndarray] | None:
    """The arrays saved at ``path`` for ``key``; ``None`` if missing, unreadable, stale or corrupt."""
    if not path.exists():
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {name: data[name] for name in data.files}
        stored_key = str(arrays.pop("__key__"))
        digest = str(arrays.pop("__digest__"))
    except Exception as exc:  # noqa: BLE001 - any failure to read means "rebuild"
        log.warning("cache file %s is unreadable (%s: %s); rebuilding it", path, type(exc).__name__, exc)
        return None
    if stored_key != key:
        log.info("cache file %s was built for another key; rebuilding it", path)
        return None
    if digest != _arrays_digest(arrays):
        log.warning("cache file %s is corrupt (content hash mismatch); rebuilding it", path)
        return None
    return arrays


def save_file(path: Path, key: str, data: bytes) -> None:
    """Store ``data`` at ``path`` plus a sidecar ``<path>.json`` holding ``key`` and its sha256."""
    write_atomic(path, data)
    write_atomic(path.with_name(path.name + ".json"), json.dumps({"key": key, "sha256": sha256_bytes(data)}).encode())


def load_file(path: Path, key: str) -> bytes | None:
    """The bytes saved at ``path`` for ``key``; ``None`` if missing, stale or corrupt."""
    meta_path = path.with_name(path.name + ".json")
    try:
        meta = json.loads(meta_path.read_text())
        data = path.read_bytes()
    except (OSError, ValueError):
        return None
    if meta.get("key") != key:
        return None
    if meta.get("sha256") != sha256_bytes(data):
        log.warning("cache file %s is corrupt (content hash mismatch); rebuilding it", path)
        return None
    return data

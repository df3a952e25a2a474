"""Units of work as cached Prefect tasks.

A *unit* is the smallest piece of a stage that is cached on its own (one synthesis shard,
one specialist, the merge step of a stage).  Every unit task takes a :class:`UnitSpec` as
its first argument; the spec carries the unit's cache key, its folder and the MLflow run
it logs to.  The cache policy below makes Prefect serve a finished unit from its result
record *only if* the files in the unit's manifest are still there and unaltered; if
anything is missing or edited, the record is dropped and the unit recomputes.

Executed units append one line to ``<workdir>/executions.log`` (``<stage>/<unit> <key>``),
which is how tests (and curious users) see what a run really recomputed.
"""

from __future__ import annotations

import fcntl
import logging
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from prefect.cache_policies import CachePolicy

from tasks.artifacts import (MANIFEST_NAME, Manifest, atomic_write_text, file_lock, lock_path, recorded_folder,
                             unit_folder, unit_key, valid_manifest, write_manifest)

log = logging.getLogger("multigrasp")

EXECUTIONS_LOG = "executions.log"


@dataclass(frozen=True)
class UnitSpec:
    """Identity and destination of one unit of work (small, picklable, no tensors)."""

    stage: str
    unit: str
    key: str
    workdir: str
    code: str
    upstream: Mapping[str, str] = field(default_factory=dict)
    run_id: str | None = None
    """MLflow run the unit logs to (not part of the key)."""
    tracking_uri: str | None = None
    """MLflow tracking URI (passed explicitly: process workers do not share the parent's state)."""

    @property
    def folder(self) -> Path:
        return unit_folder(Path(self.workdir), self.stage, self.key)

    @property
    def records_dir(self) -> Path:
        return records_dir(Path(self.workdir))

    @property
    def label(self) -> str:
        return f"{self.stage}/{self.unit}"


def records_dir(workdir: Path) -> Path:
    """Where Prefect keeps result records (``PREFECT_LOCAL_STORAGE_PATH``)."""
    return Path(workdir) / "prefect" / "results"


def make_spec(*, stage: str, unit: str, section_digest: str, upstream: Mapping[str, str], code: str,
              workdir: Path, run_id: str | None = None, tracking_uri: str | None = None) -> UnitSpec:
    """Build a unit spec, computing its cache key."""
    key = unit_key(stage, unit, section_digest, upstream, code)
    return UnitSpec(stage=stage, unit=unit, key=key, workdir=str(workdir), code=code,
                    upstream=dict(upstream), run_id=run_id, tracking_uri=tracking_uri)


class VerifiedUnitCache(CachePolicy):
    """Cache key = the unit's key; a hit counts only if its manifest's files verify.

    Prefect's default policy hashes inputs + the run id, so a fresh invocation would
    recompute everything.  Here the key is fully determined by the spec (config digest,
    upstream manifest hashes, component code version).  Before Prefect looks the key up,
    the unit's files are verified; if they are missing or altered the stale result record
    is deleted, so Prefect runs the task again.
    """

    def compute_key(self, task_ctx, inputs: dict[str, Any], flow_parameters: dict[str, Any], **kwargs: Any):
        spec: UnitSpec = inputs["spec"]
        record = spec.records_dir / spec.key
        if valid_manifest(spec.folder) is None:
            if record.exists():
                log.info("%s: cached files missing or altered; recomputing", spec.label)
                record.unlink(missing_ok=True)
        elif moved(spec) and record.exists():
            # the work dir was moved or copied: the record holds a manifest naming the old folder, so drop it and
            # let run_unit serve the verified files of this folder (nothing is recomputed)
            record.unlink(missing_ok=True)
        return spec.key


def moved(spec: UnitSpec) -> bool:
    """Whether the unit's manifest was written in another folder (its work dir was moved or copied since)."""
    recorded = recorded_folder(spec.folder)
    return recorded is not None and recorded != str(Path(spec.folder).absolute())


def record_execution(spec: UnitSpec) -> None:
    """Append ``<stage>/<unit> <key>`` to the work dir's executions log (process-safe)."""
    path = Path(spec.workdir) / EXECUTIONS_LOG
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        handle.write(f"{spec.label} {spec.key}\n")
        fcntl.flock(handle, fcntl.LOCK_UN)


def executions(workdir: Path) -> list[str]:
    """Labels of every unit executed (not served from cache) in this work dir, in order."""
    path = Path(workdir) / EXECUTIONS_LOG
    return [line.split()[0] for line in path.read_text().splitlines()] if path.exists() else []


@dataclass
class UnitOutput:
    """What a unit's body returns: its files (logical name → path inside the folder) and numbers."""

    files: dict[str, Path]
    metrics: dict[str, float] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)


def run_unit(spec: UnitSpec, body: Callable[[Path], UnitOutput]) -> Manifest:
    """Run a unit body into its folder and write its manifest; reuse a valid one on disk.

    If the Prefect record was lost but the folder already holds a verified manifest for the
    same key (e.g. the records folder was deleted), the work is not redone.  The body runs under the unit's lock
    (:func:`tasks.artifacts.file_lock`): another invocation on the same work dir that reaches the same unit waits
    for it and then serves its outputs, instead of computing it a second time into the same folder.
    """
    existing = valid_manifest(spec.folder)
    if existing is not None:
        log.info("%s: reusing verified outputs in %s", spec.label, spec.folder)
        if moved(spec):  # record the folder the files are in now (read_manifest already serves them from here)
            atomic_write_text(spec.folder / MANIFEST_NAME, existing.model_dump_json(indent=2) + "\n")
        return existing
    waited: list[str] = []

    def waiting(holder: str) -> None:
        waited.append(holder)
        log.warning("%s: another invocation on this work dir is computing it (%s); waiting for it", spec.label, holder)

    with file_lock(lock_path(Path(spec.workdir), spec.key), on_wait=waiting):
        finished = valid_manifest(spec.folder)  # by the invocation we waited for
        if finished is not None:
            log.warning("%s: finished by the other invocation; using its outputs", spec.label)
            return finished
        if waited:  # say so, or the waiting line above would be the last word on this unit until it finishes
            log.warning("%s: the other invocation ended without finishing it; computing it here", spec.label)
        spec.folder.mkdir(parents=True, exist_ok=True)
        record_execution(spec)
        start = time.perf_counter()
        out = body(spec.folder)
        return write_manifest(stage=spec.stage, unit=spec.unit, key=spec.key, folder=spec.folder,
                              files=out.files, code=spec.code, metrics=out.metrics, meta=out.meta,
                              upstream=spec.upstream, producer_run_id=spec.run_id,
                              seconds=time.perf_counter() - start)

"""A thin MLflow adapter that always names its run explicitly.

MLflow's "active run" is thread-local and torchrl's logger calls ``start_run`` without
``nested``, so neither works under a Prefect task runner.  Everything here goes through
``MlflowClient`` with explicit run ids, which is safe from threads and processes.

Store: ``MLFLOW_TRACKING_URI`` if set, else the embedded default
``sqlite:///<workdir>/mlflow.db`` with artifacts in ``<workdir>/mlartifacts``.
Runs: one parent run per CLI invocation, one child run per stage (tag ``stage``); a stage
served from cache gets a child run tagged ``cached=true`` and ``cached_from_run=<id>``.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from tasks.artifacts import file_lock, lock_path

#: the MLflow experiment of a config that names none (``tracking.experiment``), and of ``multigrasp report``'s run
DEFAULT_EXPERIMENT = "multigrasp"

log = logging.getLogger("multigrasp")

MAX_PARAM_CHARS = 6000


#: git calls of :func:`provenance_tags` give up after this long (a network file system, a huge tree)
GIT_TIMEOUT_S = 10.0
#: the commit of an installation outside a git checkout, where its builder recorded one (docker/Dockerfile)
GIT_COMMIT_ENV = "MULTIGRASP_GIT_COMMIT"


def _git(repo: Path, *args: str) -> str | None:
    import subprocess

    try:
        out = subprocess.run(["git", "-C", str(repo), *args], capture_output=True, text=True, timeout=GIT_TIMEOUT_S)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() if out.returncode == 0 else None


def provenance_tags(repo: Path | None = None) -> dict[str, str]:
    """What produced a run, as MLflow tags of every top-level run (an invocation, an evaluation): the package
    version, the git commit of the checkout it runs from (``mlflow.source.git.commit``, shown by the MLflow UI) and
    whether that checkout had uncommitted changes to tracked files, torch and Python.  An installation outside a
    git checkout gets the commit of ``$MULTIGRASP_GIT_COMMIT`` if its builder set it (the docker image), else no git
    tags."""
    import platform
    from importlib import metadata

    from tasks.artifacts import REPO_ROOT

    repo = REPO_ROOT if repo is None else repo

    def installed(package: str) -> str:  # the installed version without importing it (torch: ~4 s on a slow day)
        try:
            return metadata.version(package)
        except metadata.PackageNotFoundError:
            return "unknown"

    tags = {"multigrasp.version": installed("multigrasp"), "multigrasp.torch": installed("torch"),
            "multigrasp.python": platform.python_version()}
    commit = _git(repo, "rev-parse", "HEAD") if (repo / ".git").exists() else None
    if commit:
        tags["mlflow.source.git.commit"] = commit
        changes = _git(repo, "status", "--porcelain", "--untracked-files=no")
        if changes is not None:
            tags["multigrasp.git_dirty"] = str(bool(changes)).lower()
    elif os.environ.get(GIT_COMMIT_ENV):  # an image built without .git (docker/Dockerfile's GIT_COMMIT build arg)
        tags["mlflow.source.git.commit"] = os.environ[GIT_COMMIT_ENV]
    return tags


def version_line(repo: Path | None = None) -> str:
    """``multigrasp --version``: the package, its checkout's commit, torch and Python, from :func:`provenance_tags`."""
    tags = provenance_tags(repo)
    git = ""
    if "mlflow.source.git.commit" in tags:
        dirty = ", uncommitted changes" if tags.get("multigrasp.git_dirty") == "true" else ""
        git = f" (git {tags['mlflow.source.git.commit'][:12]}{dirty})"
    return f"multigrasp {tags['multigrasp.version']}{git}, torch {tags['multigrasp.torch']}, Python {tags['multigrasp.python']}"


def default_tracking_uri(workdir: Path) -> str:
    """``MLFLOW_TRACKING_URI`` if set, else the embedded sqlite store of the work dir."""
    return os.environ.get("MLFLOW_TRACKING_URI") or f"sqlite:///{Path(workdir).resolve() / 'mlflow.db'}"


def artifact_root(workdir: Path) -> str:
    """Artifact location for experiments created in the embedded store."""
    return (Path(workdir).resolve() / "mlartifacts").as_uri()


#: Columns of the embedded store that hold artifact locations (table, column); tables an MLflow version lacks are skipped.
ARTIFACT_COLUMNS = (("experiments", "artifact_location"), ("runs", "artifact_uri"), ("logged_models", "artifact_location"))


def relocate_embedded_store(workdir: Path) -> str | None:
    """Point the embedded store's artifact locations at this work dir's ``mlartifacts``, if they name another place.

    MLflow stores absolute artifact URIs in ``mlflow.db``.  After a work dir is moved or copied (rsync from a cluster
    to a laptop), new runs would log their artifacts to the old place and the UI would look for the old runs' PNGs
    there.  Every location under the old ``.../mlartifacts`` is rewritten to the same path under this work dir's.
    Returns the old root when it rewrote something, else None.  Only the embedded sqlite store of the work dir is
    touched (not a store named by ``MLFLOW_TRACKING_URI``), and only locations under its ``mlartifacts``.
    """
    import sqlite3

    db = Path(workdir).resolve() / "mlflow.db"
    if os.environ.get("MLFLOW_TRACKING_URI") or not db.is_file():
        return None
    new_root = artifact_root(workdir)
    with sqlite3.connect(db) as conn:
        tables = {row[0] for row in conn.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        if "experiments" not in tables:
            return None
        old_roots = {loc for (loc,) in conn.execute(
            "SELECT artifact_location FROM experiments WHERE artifact_location LIKE 'file:%/mlartifacts'")}
        old_roots.discard(new_root)
        if not old_roots:
            return None
        for old in old_roots:
            for table, column in ARTIFACT_COLUMNS:
                if table in tables:
                    conn.execute(f"UPDATE {table} SET {column} = ? || substr({column}, ?) "
                                 f"WHERE {column} = ? OR substr({column}, 1, ?) = ?",
                                 (new_root, len(old) + 1, old, len(old) + 1, old + "/"))
    old = sorted(old_roots)[0]
    log.info("MLflow store of %s: artifact locations moved from %s to %s", workdir, old, new_root)
    return old


def ui_command(workdir: Path) -> str:
    """The shell command that opens the MLflow UI on this work dir's store."""
    return "multigrasp ui --workdir " + str(workdir)


def flatten(tree: Mapping[str, Any], prefix: str = "") -> dict[str, str]:
    """``{"a": {"b": 1}}`` → ``{"a.b": "1"}`` (lists become their JSON-ish repr)."""
    flat: dict[str, str] = {}
    for key, value in tree.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(flatten(value, name + "."))
        else:
            flat[name] = str(value)[:MAX_PARAM_CHARS]
    return flat


class Tracker:
    """Explicit-run-id MLflow logging for one work dir / tracking URI."""

    def __init__(self, tracking_uri: str, experiment: str, workdir: Path):
        import mlflow  # noqa: F401  (heavy import kept out of module import time)
        from mlflow.tracking import MlflowClient

        self.tracking_uri = tracking_uri
        self._provenance: dict[str, str] | None = None  # provenance_tags(), read at the first top-level run
        # one invocation at a time creates (and migrates) the store and the experiment: two started together on a
        # new work dir raced in MLflow's schema migration ("duplicate column name: step") and the second crashed
        with file_lock(lock_path(workdir, "mlflow")):
            if tracking_uri == default_tracking_uri(workdir):
                relocate_embedded_store(workdir)  # a moved or copied work dir logs its artifacts where it is now
            self.client = MlflowClient(tracking_uri)
            found = self.client.get_experiment_by_name(experiment)
            if found is None:
                location = artifact_root(workdir) if tracking_uri.startswith("sqlite:") else None
                self.experiment_id = self.client.create_experiment(experiment, artifact_location=location)
            else:
                self.experiment_id = found.experiment_id

    # ------------------------------------------------------------------ runs
    def start_run(self, name: str, parent_id: str | None = None, tags: Mapping[str, str] | None = None) -> str:
        """Create a run (a child of ``parent_id`` if given) and return its id."""
        all_tags = dict(tags or {})
        if parent_id:
            all_tags["mlflow.parentRunId"] = parent_id
        else:  # a top-level run records what produced it; its stage runs are its children
            if self._provenance is None:
                self._provenance = provenance_tags()
            all_tags = {**self._provenance, **all_tags}
        run = self.client.create_run(self.experiment_id, run_name=name, tags=all_tags)
        return run.info.run_id

    def end_run(self, run_id: str, status: str = "FINISHED") -> None:
        self.client.set_terminated(run_id, status=status)

    def set_tags(self, run_id: str, tags: Mapping[str, Any]) -> None:
        for key, value in tags.items():
            self.client.set_tag(run_id, key, str(value))

    # ------------------------------------------------------------------ data
    def log_params(self, run_id: str, params: Mapping[str, Any]) -> None:
        from mlflow.entities import Param

        items = [Param(k, str(v)[:MAX_PARAM_CHARS]) for k, v in params.items()]
        for start in range(0, len(items), 100):
            self.client.log_batch(run_id, params=items[start:start + 100])

    def log_metrics(self, run_id: str, metrics: Mapping[str, float], step: int = 0) -> None:
        from mlflow.entities import Metric
        import time

        now = int(time.time() * 1000)
        items = [Metric(k, float(v), now, step) for k, v in metrics.items()
                 if v is not None and math.isfinite(float(v))]
        for start in range(0, len(items), 500):
            self.client.log_batch(run_id, metrics=items[start:start + 500])

    def log_artifact(self, run_id: str, path: Path, artifact_path: str | None = None) -> None:
        self.client.log_artifact(run_id, str(path), artifact_path)

    def log_text(self, run_id: str, text: str, artifact_file: str) -> None:
        self.client.log_text(run_id, text, artifact_file)

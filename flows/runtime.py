"""What every flow needs around it: Prefect settings, the task runner, progress, MLflow runs."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from rich.console import Console

from components.errors import MultigraspError
from flows.config import PipelineConfig, RunConfig
from tasks.artifacts import Manifest, upstream_hashes
from tasks.tracking import Tracker, default_tracking_uri, flatten
from tasks.units import UnitSpec, make_spec, records_dir

log = logging.getLogger("multigrasp")

SERVER_START_TIMEOUT_S = 90.0
RAY_MISSING = "run.runner=ray needs prefect-ray: pip install 'multigrasp[ray]' (or use threads/processes)"
PREFECT_DRAIN_TIMEOUT_S = 30.0  # at most this long to send queued run logs and events before the server stops


def prefect_defaults() -> None:
    """Environment defaults for Prefect (user values win); see ``tasks/__init__.py``."""
    from tasks import PREFECT_ENV_DEFAULTS

    for name, value in PREFECT_ENV_DEFAULTS.items():
        os.environ.setdefault(name, value)


#: glibc's mallopt parameters and the environment variables it reads at a process's start (malloc.h).
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3
ALLOCATOR_ENV = {"MALLOC_MMAP_THRESHOLD_": M_MMAP_THRESHOLD, "MALLOC_TRIM_THRESHOLD_": M_TRIM_THRESHOLD}


def apply_allocator(run: RunConfig) -> dict[str, int]:
    """glibc malloc settings of ``run`` (``malloc_mmap_threshold_mb``, ``malloc_trim_threshold_mb``) for this
    process (``mallopt``) and, through the environment, for the worker processes it starts (Prefect's process
    runner, the evaluation's pool, collectors), which read ``MALLOC_*_`` at their start.

    A value of 0, or an environment variable the user set to another value, leaves that setting alone; so does a C
    library without ``mallopt`` (not glibc: macOS, musl).  Returns the settings applied, in bytes, by variable."""
    import ctypes

    wanted = {"MALLOC_MMAP_THRESHOLD_": run.malloc_mmap_threshold_mb, "MALLOC_TRIM_THRESHOLD_": run.malloc_trim_threshold_mb}
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return {}
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    applied = {}
    for name, megabytes in wanted.items():
        value = megabytes * 1024 * 1024
        if not megabytes or os.environ.get(name, str(value)) != str(value):
            continue
        if mallopt(ALLOCATOR_ENV[name], value) == 1:  # RunConfig bounds keep value within a C int
            os.environ[name] = str(value)
            applied[name] = value
    return applied


def _local_prefect_database() -> Path | None:
    """The SQLite file of Prefect's local database (``$PREFECT_HOME/prefect.db`` by default), or None where this
    invocation will use a server of the user's (``PREFECT_API_URL``) or a database that is not SQLite."""
    if os.environ.get("PREFECT_API_URL"):
        return None
    from prefect.settings import get_current_settings
    from sqlalchemy.engine import make_url

    url = make_url(get_current_settings().server.database.connection_url.get_secret_value())
    if not url.drivername.startswith("sqlite") or not url.database or url.database == ":memory:":
        return None
    return Path(url.database).expanduser()


def prepare_prefect_database(workdir: Path) -> None:
    """Let one Prefect server set up Prefect's local database, under a lock, before this invocation starts its own.

    Every Prefect server migrates its database and registers Prefect's block types in it as it starts.  Two
    invocations starting at once on a fresh ``PREFECT_HOME`` (two terminals on a new machine, or ``make test``'s
    two workers in a fresh CI clone) did both on the same SQLite file together: alembic's "Online migration expected
    to match one row" or "UNIQUE constraint failed: block_schema" tracebacks on the console, and with ``--runner
    processes`` "could not start a local Prefect server".  The first invocation now starts and stops one server
    (``local_prefect_server``, ~15 s once) while the others wait on the lock; a stamp beside the database, named after
    the Prefect version, lets later invocations skip this.  Prefect itself skips both steps on a set-up database."""
    import prefect

    from tasks.artifacts import file_lock

    database = _local_prefect_database()
    if database is None:
        return
    stamp = database.parent / f".multigrasp-prepared-{prefect.__version__}"
    if stamp.is_file() and database.is_file():
        return
    console = make_console()
    with file_lock(database.parent / ".multigrasp-prepare.lock",
                   on_wait=lambda holder: console.print(f"waiting for {holder} to set up Prefect's database")):
        if stamp.is_file() and database.is_file():  # another invocation prepared it while this one waited
            return
        console.print(f"setting up Prefect's local database {database} (once per Prefect version, ~15 s)")
        try:
            with local_prefect_server(workdir):  # up once it has migrated the database and registered the blocks
                pass
        except MultigraspError as exc:  # the run's own server will try itself, as it did before this step
            log.warning("could not prepare Prefect's database %s: %s", database, exc)
            return
        stamp.write_text(f"set up by a Prefect {prefect.__version__} server started by multigrasp\n")


def make_task_runner(run: RunConfig):
    """The configured Prefect task runner for fan-out."""
    from prefect.task_runners import ProcessPoolTaskRunner, ThreadPoolTaskRunner

    if run.runner == "threads":
        return ThreadPoolTaskRunner(max_workers=run.max_workers)
    if run.runner == "processes":
        return ProcessPoolTaskRunner(max_workers=run.max_workers)
    try:
        from prefect_ray import RayTaskRunner
    except ImportError:
        raise MultigraspError(RAY_MISSING) from None
    return RayTaskRunner(address=run.ray_address) if run.ray_address else RayTaskRunner()


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@contextlib.contextmanager
def local_prefect_server(workdir: Path) -> Iterator[str]:
    """Start one ``prefect server`` on 127.0.0.1 for this invocation and stop it after.

    Process-based runners otherwise start a temporary server *per worker* (DESIGN §7);
    sharing one keeps fan-out to processes cheap.
    """
    import urllib.request

    port = _free_port()
    url = f"http://127.0.0.1:{port}/api"
    logfile = open(Path(workdir) / "prefect-server.log", "ab")
    proc = subprocess.Popen([sys.executable, "-m", "prefect", "server", "start", "--host", "127.0.0.1",
                             "--port", str(port)], stdout=logfile, stderr=subprocess.STDOUT,
                            env={**os.environ, "PREFECT_UI_ENABLED": "false"})
    try:
        deadline = time.monotonic() + SERVER_START_TIMEOUT_S
        while True:
            try:
                urllib.request.urlopen(url + "/health", timeout=2)
                break
            except OSError:
                if proc.poll() is not None or time.monotonic() > deadline:
                    raise MultigraspError(f"could not start a local Prefect server (see {logfile.name}); "
                                          "set PREFECT_API_URL to a running one or use run.runner=threads") from None
                time.sleep(0.5)
        yield url
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()
        logfile.close()


def _drain_prefect_workers() -> None:
    """Send Prefect's queued run logs and events to this run's server before it goes away.  Left to Prefect's own
    exit handlers, they are sent after the server has stopped, and Prefect starts a temporary server just for
    them (a few seconds, "Still processing items" warnings after the CLI's summary)."""
    try:
        from prefect.events.worker import EventsWorker
        from prefect.logging.handlers import APILogHandler

        APILogHandler.flush()
        EventsWorker.drain_all(timeout=PREFECT_DRAIN_TIMEOUT_S)
    except Exception as exc:  # noqa: BLE001 - logs and events are best effort; never fail a finished run
        log.debug("could not drain Prefect's log and event workers: %s", exc)


def _refresh_prefect_global_settings() -> None:
    """Make threads that carry no settings context of their own (Prefect's process-pool message forwarder and its
    global event-loop thread) read the current environment: they fall back to the global settings Prefect built at
    import, which lack this run's ``PREFECT_API_URL``, and each started a temporary server of its own."""
    from prefect.context import refresh_global_settings_context

    refresh_global_settings_context()


class HideUserErrorTracebacks(logging.Filter):
    """Drop two kinds of Prefect traceback records that tell the user nothing:

    * a :class:`MultigraspError` (the CLI prints it as one line);
    * an ``asyncio.CancelledError`` logged by Prefect's in-process server (``prefect.server.*``, e.g. the
      task-run recorder's "Error flushing 1 events") when the interpreter exits after a finished run and
      cancels the server's background services: the run and its results are complete by then, yet the
      traceback printed after the CLI's summary read like a failure."""

    def filter(self, record: logging.LogRecord) -> bool:
        exc = record.exc_info[1] if record.exc_info else None
        if isinstance(exc, MultigraspError):
            return False
        return not (isinstance(exc, asyncio.CancelledError) and record.name.startswith("prefect.server"))


@contextlib.contextmanager
def prefect_context(cfg: PipelineConfig) -> Iterator[None]:
    """Prefect settings for this work dir: results persisted under ``<workdir>/prefect``."""
    prefect_defaults()
    from prefect.logging.configuration import ensure_logging_setup

    ensure_logging_setup()
    if os.environ.get("PREFECT_LOGGING_LEVEL", "WARNING") != "INFO":
        logging.getLogger("mlflow").setLevel(logging.WARNING)  # mlflow resets its level on import
    for handler in [h for name in ("prefect", "") for h in logging.getLogger(name).handlers]:
        if not any(isinstance(f, HideUserErrorTracebacks) for f in handler.filters):
            handler.addFilter(HideUserErrorTracebacks())
    from prefect.settings import (PREFECT_API_URL, PREFECT_LOCAL_STORAGE_PATH, PREFECT_LOGGING_TO_API_ENABLED,
                                  PREFECT_RESULTS_PERSIST_BY_DEFAULT, temporary_settings)

    workdir = cfg.run.workdir
    prepare_prefect_database(workdir)
    records = records_dir(workdir)
    records.mkdir(parents=True, exist_ok=True)
    updates = {PREFECT_LOCAL_STORAGE_PATH: str(records), PREFECT_RESULTS_PERSIST_BY_DEFAULT: True}
    with contextlib.ExitStack() as stack:
        if needs_run_server(cfg.run) and not os.environ.get("PREFECT_API_URL"):
            url = stack.enter_context(local_prefect_server(workdir))
            updates[PREFECT_API_URL] = url
            # process workers read the environment, not this process's settings context
            # Run logs are not sent to this short-lived server: Prefect's log worker would flush
            # them at interpreter exit, after the server is gone, and start a temporary server
            # just for that (~1 min on 2 cores). Progress is printed and tracked in MLflow.
            updates[PREFECT_LOGGING_TO_API_ENABLED] = False
            stack.callback(_refresh_prefect_global_settings)  # unwound after the environment is restored
            stack.enter_context(_environ({"PREFECT_API_URL": url, "PREFECT_LOCAL_STORAGE_PATH": str(records),
                                          "PREFECT_LOGGING_TO_API_ENABLED": "false"}))
            _refresh_prefect_global_settings()
        stack.enter_context(temporary_settings(updates=updates))
        if PREFECT_API_URL in updates:  # this run started its own server
            stack.callback(_drain_prefect_workers)  # unwound first, while the server and its settings are in place
        if cfg.run.runner == "ray":
            stack.enter_context(ray_session(cfg.run, records))
        yield


def needs_run_server(run: RunConfig) -> bool:
    """Whether the invocation starts one local Prefect server for its workers: process workers, and the workers of
    a local Ray (each would otherwise start a temporary server of its own).  A Ray cluster (``run.ray_address``)
    cannot reach a server on this machine's 127.0.0.1: give it one through ``PREFECT_API_URL``."""
    return run.runner == "processes" or (run.runner == "ray" and not run.ray_address)


#: the Prefect settings a Ray worker needs from the driver (read from the environment when present)
RAY_WORKER_ENV = ("PREFECT_API_URL", "PREFECT_LOGGING_TO_API_ENABLED", "PREFECT_RESULTS_PERSIST_BY_DEFAULT")


@contextlib.contextmanager
def ray_session(run: RunConfig, records: Path) -> Iterator[None]:
    """One Ray instance for the whole invocation (local, or ``run.ray_address``).  prefect-ray's runner starts and
    shuts down a Ray of its own per flow when none is running, so a pipeline of several stages paid Ray's start
    (and its workers' imports) once per stage; with this session every stage's runner finds Ray initialised and
    reuses it and its warm workers.  The workers get this run's Prefect settings (``RAY_WORKER_ENV`` and the
    results folder) through the runtime environment, so a worker on another node reports to the same server."""
    try:
        import prefect_ray  # noqa: F401  (the stages' runner: missing, it would fail only at the first stage)
        import ray
    except ImportError:
        raise MultigraspError(RAY_MISSING) from None
    if ray.is_initialized():  # the caller's own Ray (a notebook, a test): use it, leave it running
        yield
        return
    env = {name: os.environ[name] for name in RAY_WORKER_ENV if name in os.environ}
    env["PREFECT_LOCAL_STORAGE_PATH"] = str(records)
    local = {} if run.ray_address else {"include_dashboard": False}  # options only a new local Ray takes
    ray.init(address=run.ray_address, namespace="prefect", runtime_env={"env_vars": env}, **local)
    try:
        yield
    finally:
        ray.shutdown()


@contextlib.contextmanager
def _environ(values: dict[str, str]) -> Iterator[None]:
    old = {k: os.environ.get(k) for k in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for key, value in old.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


# --------------------------------------------------------------------------- run context


@dataclass
class StageResult:
    """A finished stage: its output manifest and how its units were obtained."""

    name: str
    manifest: Manifest
    executed: int
    cached: int
    seconds: float
    run_id: str | None = None

    @property
    def fully_cached(self) -> bool:
        return self.executed == 0


@dataclass
class RunContext:
    """Per-invocation state handed from the CLI to the flows (never module-level)."""

    cfg: PipelineConfig
    tracker: Tracker
    parent_run_id: str
    console: Console = field(default_factory=lambda: make_console())
    results: dict[str, StageResult] = field(default_factory=dict)

    @property
    def workdir(self) -> Path:
        return self.cfg.run.workdir

    @property
    def tracking_uri(self) -> str:
        return self.tracker.tracking_uri


def make_console() -> Console:
    """Progress goes to stderr; soft wrap keeps lines whole in logs and pipes."""
    return Console(stderr=True, soft_wrap=True)


def make_tracker(cfg: PipelineConfig) -> Tracker:
    cfg.run.workdir.mkdir(parents=True, exist_ok=True)
    return Tracker(default_tracking_uri(cfg.run.workdir), cfg.tracking.experiment, cfg.run.workdir)


def stage_params(cfg: PipelineConfig, settings: Sequence[str]) -> dict[str, str]:
    """The config's values under each dotted path of ``settings``, flattened to MLflow params (``synthesis.optimizer.
    batch_size`` → ``"256"``)."""
    tree = cfg.model_dump(mode="json")
    params: dict[str, str] = {}
    for path in settings:
        node = tree
        for part in path.split("."):
            node = node[part]
        params.update(flatten(node, path + ".") if isinstance(node, dict) else {path: str(node)})
    return params


def unit_task(task):
    """``task`` (a unit task of ``tasks/``, whose first parameter is its ``spec``) with its runs named after their
    unit, ``synthesize/shard-Pl:cube+mug:0`` instead of Prefect's ``synthesize-shard-3e1``, in Prefect's log lines
    (``--verbose``) and in the UI of a shared Prefect server.  Named here, not in ``tasks/``, whose code is part of
    the stages' cache keys; the name is not (:class:`tasks.units.VerifiedUnitCache` keys on the spec alone)."""
    return task.with_options(task_run_name="{spec.label}")


def start_evaluation_run(tracker: Tracker, cfg: PipelineConfig, name: str, results_file: str,
                         parent_run_id: str | None, tags: dict[str, str]) -> str:
    """An evaluation's MLflow run with the settings its figures can depend on as params
    (:func:`flows.config.evaluation_settings`) and their digest as the ``config_key`` tag, as its results file holds
    it: a ``multigrasp evaluate`` alone is a top-level run, which had no params to compare by."""
    from flows.config import evaluation_key, evaluation_settings

    run_id = tracker.start_run(name, parent_run_id, tags={**tags, "config_key": evaluation_key(cfg, results_file)})
    tracker.log_params(run_id, flatten(evaluation_settings(cfg, results_file)))
    return run_id


def start_stage_run(tracker: Tracker, cfg: PipelineConfig, stage: str, settings: Sequence[str],
                    parent_run_id: str) -> str:
    """A stage's MLflow run, a child of the invocation's, with the settings it reads as params: the parent holds the
    whole config, but MLflow compares runs by their own params, so two runs' ``synthesize`` children differed there
    in metrics only."""
    run_id = tracker.start_run(stage, parent_id=parent_run_id, tags={"stage": stage})
    tracker.log_params(run_id, stage_params(cfg, settings))
    return run_id


# --------------------------------------------------------------------------- progress


class StageProgress:
    """Per-stage log lines with counts and an ETA as units finish."""

    def __init__(self, console: Console, stage: str, total: int):
        self.console, self.stage, self.total = console, stage, total
        self.done = self.cached = 0
        self.start = time.monotonic()

    def unit_finished(self, label: str, cached: bool) -> None:
        self.done += 1
        self.cached += int(cached)
        elapsed = time.monotonic() - self.start
        executed = self.done - self.cached
        remaining = self.total - self.done
        eta = "" if remaining == 0 or executed == 0 else f", ETA {elapsed / max(executed, 1) * remaining:.0f}s"
        how = "cached" if cached else "computed"
        self.console.print(f"[bold cyan]{self.stage}[/] {self.done}/{self.total} {label} ({how}) "
                           f"elapsed {elapsed:.0f}s{eta}")


def wait_units(futures: Sequence, progress: StageProgress, run_id: str | None) -> tuple[list[Manifest], int]:
    """Wait for unit futures in completion order; return manifests (in submit order) and #cached.

    A unit counts as served from cache when its manifest was produced by another MLflow run
    than this stage's ``run_id`` (a Prefect cache hit, or verified outputs reused on disk).
    Raises the first unit failure after all others have finished, so finished units are kept.
    """
    from prefect.futures import as_completed

    index = {id(f): i for i, f in enumerate(futures)}
    manifests: list[Manifest | None] = [None] * len(futures)
    cached = 0
    failure: BaseException | None = None
    for future in as_completed(list(futures)):
        try:
            manifest = future.result()
        except BaseException as exc:  # noqa: BLE001 - re-raised after the others finish
            failure = failure or exc
            progress.console.print(f"[bold red]{progress.stage}[/] unit failed: {exc}")
            continue
        is_cached = manifest.producer_run_id != run_id
        cached += int(is_cached)
        manifests[index[id(future)]] = manifest
        progress.unit_finished(f"{manifest.unit}", is_cached)
    if failure is not None:
        raise failure
    return [m for m in manifests if m is not None], cached


def single_unit(stage: str, future, progress: StageProgress, run_id: str) -> StageResult:
    """Wait for a one-unit stage's unit: the stage's result (executed here or served from cache)."""
    (manifest,), cached = wait_units([future], progress, run_id)
    return StageResult(stage, manifest, executed=1 - cached, cached=cached, seconds=0.0, run_id=run_id)


def log_loss_history(tracker, result: StageResult, artifact_path: str) -> None:
    """MLflow for a training stage: its manifest metrics; when trained in this run, the loss of every row of
    its ``history`` file as a metric with steps and its ``loss_plot`` PNG."""
    import json

    tracker.log_metrics(result.run_id, result.manifest.metrics)
    if result.fully_cached:
        return
    for row in json.loads(result.manifest.path("history").read_text()):
        tracker.log_metrics(result.run_id, {"loss": row["loss"]}, step=row["step"])
    tracker.log_artifact(result.run_id, result.manifest.path("loss_plot"), artifact_path)


def merge_unit_spec(cfg: PipelineConfig, stage: str, shards: list[Manifest], section_digest: str, code: str,
                    run_id: str | None = None, tracking_uri: str | None = None) -> UnitSpec:
    """Spec of a shards-then-merge stage's ``merge`` unit: keyed by the stage's merge settings
    (``section_digest``), the shard manifests it combines and the merge code (``code``)."""
    return make_spec(stage=stage, unit="merge", section_digest=section_digest,
                     upstream=upstream_hashes((m.unit, m) for m in shards), code=code, workdir=cfg.run.workdir,
                     run_id=run_id, tracking_uri=tracking_uri)


def planned_shards_and_merge(shard_specs: list, merge_spec_of: Callable[[list[Manifest]], object]) -> list:
    """Unit specs knowable now for a shards-then-merge stage (``multigrasp status``): every shard, plus the
    merge once every shard has a valid manifest (its key depends on them)."""
    from tasks.artifacts import valid_manifest

    manifests = [valid_manifest(spec.folder) for spec in shard_specs]
    if all(m is not None for m in manifests):
        return [*shard_specs, merge_spec_of(manifests)]
    return list(shard_specs)


def shards_then_merge(stage: str, shard_futures: Sequence, submit_merge: Callable[[list[Manifest]], object],
                      progress: StageProgress, run_id: str) -> StageResult:
    """Wait for a stage's shard units, submit its merge unit on their manifests, wait for it: the stage's
    result, with how many units ran here and how many came from cache."""
    shards, cached = wait_units(shard_futures, progress, run_id)
    merged, merged_cached = wait_units([submit_merge(shards)], progress, run_id)
    total = len(shard_futures) + 1
    return StageResult(stage, merged[0], executed=total - cached - merged_cached, cached=cached + merged_cached,
                       seconds=0.0, run_id=run_id)

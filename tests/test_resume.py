"""End-to-end flow tests on fresh work dirs under the smoke profile: resume after a crash, cache hits after an edit
or a move, two invocations at once, the process runner's Prefect server, and signals.

They were in ``test_flows.py``; the tests that read its shared smoke run stayed there.  Two modules let
``make test``'s two workers (pytest-xdist, ``--dist loadfile``) share the end-to-end work evenly.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

import tasks.scenes
from flows.cli import main
from flows.config import load_config
from flows.pipeline import status
from tasks.artifacts import read_manifest
from tasks.units import executions
from tests.test_flows import SMALL, run_smoke

pytestmark = pytest.mark.slow


def test_a_user_mesh_edited_in_place_is_computed_again_and_an_untouched_one_is_served(tmp_path):
    """The stage keys held the mesh's path, not its contents: a mesh fixed and re-exported under the same name was
    served from the cache with the old geometry."""
    import trimesh

    mesh = tmp_path / "block.obj"
    trimesh.creation.box(extents=(0.04, 0.03, 0.025)).export(mesh)
    config = tmp_path / "my.yaml"
    config.write_text(f"objects:\n  user:\n    - {{name: block, mesh: {mesh}}}\n  ood: [block]\n")
    workdir = tmp_path / "runs"
    argv = ["run", "--profile", "smoke", "--workdir", str(workdir), "--config", str(config), "--until", "scenes"]
    for item in SMALL:
        argv += ["--set", item]
    assert main(argv) == 0
    first = executions(workdir)
    assert main(argv) == 0 and executions(workdir) == first  # untouched: served from cache
    trimesh.creation.box(extents=(0.05, 0.03, 0.025)).export(mesh)  # edited in place, same path
    assert main(argv) == 0
    again = executions(workdir)[len(first):]
    assert again and all(label.startswith("scenes/") for label in again)


def test_two_invocations_on_a_new_work_dir_both_finish_and_compute_each_unit_once(tmp_path):
    """A second terminal running the same command: the second crashed in MLflow's schema migration of the new
    store ("duplicate column name"), and both would have computed every unit.  Now the store is created under a
    lock, each unit under its own, and the two share the work.  On a fresh PREFECT_HOME the two Prefect servers
    also migrated the new database together, and one of them failed with an alembic traceback on the console (a
    third of the runs), or registered Prefect's block types together (a UNIQUE constraint traceback); the first
    invocation now lets one server set the database up under a lock (``flows.runtime.prepare_prefect_database``)."""
    import subprocess
    import sys

    workdir = tmp_path / "runs"
    argv = [sys.executable, "-m", "flows.cli", "run", "--profile", "smoke", "--workdir", str(workdir)]
    for item in SMALL:
        argv += ["--set", item]
    # a fresh PREFECT_HOME, as on a new machine: both servers migrated the new database at once (below)
    env = {**os.environ, "PREFECT_HOME": str(tmp_path / "prefect-home")}
    procs = [subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
             for _ in range(2)]
    outputs = [p.communicate(timeout=600)[0] for p in procs]
    assert [p.returncode for p in procs] == [0, 0], outputs
    done = executions(workdir)
    assert done and len(done) == len(set(done))  # no unit computed twice
    assert "Traceback" not in "".join(outputs)
    # no library's INFO chatter on the console: torchrl printed "Initialized LazyTensorStorage ..." in every training
    assert "[torchrl]" not in "".join(outputs) and "LazyTensorStorage" not in "".join(outputs)


def test_resume_after_downstream_failure_reuses_upstream_units(tmp_path, monkeypatch):
    real = tasks.scenes.merge_and_render

    def crash(*args, **kwargs):
        raise RuntimeError("simulated crash in the merge unit")

    monkeypatch.setattr(tasks.scenes, "merge_and_render", crash)
    with pytest.raises(RuntimeError, match="simulated crash"):
        run_smoke(tmp_path, *SMALL)
    first = executions(tmp_path)
    assert sorted(first) == ["scenes/merge", "scenes/shard-000", "scenes/shard-001"]

    monkeypatch.setattr(tasks.scenes, "merge_and_render", real)
    argv = ["run", "--profile", "smoke", "--workdir", str(tmp_path), "--until", "synthesize"]
    assert main(argv + [a for item in SMALL for a in ("--set", item)]) == 0  # the later stages add nothing here
    # only the failed unit ran again: the shards were served from the cache (then the next stage ran)
    again = executions(tmp_path)[len(first):]
    assert [e for e in again if e.startswith("scenes/")] == ["scenes/merge"]
    assert any(e.startswith("synthesize/") for e in again)


def test_a_moved_work_dir_is_served_from_its_cache_and_records_its_new_place(tmp_path):
    import shutil

    from tasks.artifacts import recorded_folder

    assert run_smoke(tmp_path / "cluster", *SMALL) == 0
    done = executions(tmp_path / "cluster")
    shutil.move(tmp_path / "cluster", tmp_path / "laptop")  # the old place is gone: nothing may be read from it
    workdir = tmp_path / "laptop"
    assert run_smoke(workdir, *SMALL) == 0
    assert executions(workdir) == done, "a moved work dir recomputed finished units"
    cfg = load_config("smoke", sets=SMALL, workdir=workdir)
    assert all(r.state == "done" for r in status(cfg))
    units = [p for stage in (workdir / "stages").iterdir() for p in stage.iterdir() if read_manifest(p) is not None]
    assert units and all(recorded_folder(p) == str(p) for p in units)  # manifests now name the new folders
    # MLflow: every run, the first invocation's too, keeps its artifacts under the moved work dir
    from mlflow.tracking import MlflowClient

    from tasks.tracking import artifact_root, default_tracking_uri

    client = MlflowClient(default_tracking_uri(workdir))
    experiment = client.get_experiment_by_name(cfg.tracking.experiment)
    assert experiment.artifact_location == artifact_root(workdir)
    runs = client.search_runs([experiment.experiment_id])
    assert len(runs) >= 4 and all(r.info.artifact_uri.startswith(artifact_root(workdir) + "/") for r in runs)
    first = min((r for r in runs if r.data.tags.get("stage") == "scenes"), key=lambda r: r.info.start_time)
    assert client.list_artifacts(first.info.run_id), "the first run's artifacts are not found after the move"
    assert not (tmp_path / "cluster").exists()


def test_process_runner_uses_only_the_runs_prefect_server_and_resumes_from_cache(tmp_path):
    """`--runner processes`: every Prefect client of the run talks to the one local server the run starts.  Prefect's
    process-pool message forwarder and its event-loop thread used to start a temporary server each (they read the
    settings Prefect built at import), and the queued events were sent after the run's server had stopped.  With
    temporary servers forbidden (PREFECT_SERVER_ALLOW_EPHEMERAL_MODE=false) any such attempt logs an ERROR."""
    import subprocess
    import sys

    argv = [sys.executable, "-m", "flows.cli", "run", "--profile", "smoke", "--workdir", str(tmp_path), "--until",
            "scenes", "--runner", "processes"] + [a for item in SMALL for a in ("--set", item)]
    env = {**os.environ, "PREFECT_SERVER_ALLOW_EPHEMERAL_MODE": "false"}
    env.pop("PREFECT_API_URL", None)
    outputs = [subprocess.run(argv, capture_output=True, text=True, timeout=300, env=env) for _ in range(2)]
    for done in outputs:
        out = done.stdout + done.stderr
        assert done.returncode == 0, out
        for bad in ("Traceback", "ERROR", "failed", "Still processing items", "temporary server"):
            assert bad not in out, out
    assert "0 served from cache" in outputs[0].stderr and "every stage served from cache" in outputs[1].stderr
    assert (tmp_path / "prefect-server.log").is_file()  # the run's own server


@pytest.mark.skipif(not __import__("os").path.isdir("/proc"), reason="reads child processes from /proc")
def test_sigterm_stops_a_run_like_ctrl_c_and_stops_its_helper_processes(tmp_path):
    """`kill PID` (or a cluster scheduler's SIGTERM) was swallowed inside a flow, or ended the CLI at once and left
    Prefect's temporary API server running; it now unwinds like Ctrl-C: exit status EXIT_INTERRUPTED (130), the
    resume hint, and the helper processes it started are gone."""
    import signal
    import subprocess
    import sys
    import time

    from flows.cli import EXIT_INTERRUPTED, _child_pids

    proc = subprocess.Popen([sys.executable, "-m", "flows.cli", "run", "--profile", "smoke", "--workdir",
                             str(tmp_path / "run")], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        seen = []
        for line in proc.stdout:  # the first stage has started: Prefect and MLflow are up
            seen.append(line)
            if line.startswith("stage scenes"):
                break
        deadline = time.monotonic() + 60
        while not _child_pids(proc.pid) and time.monotonic() < deadline:
            time.sleep(0.2)
        helpers = _child_pids(proc.pid)
        proc.send_signal(signal.SIGTERM)
        try:
            rest, _ = proc.communicate(timeout=180)
        except subprocess.TimeoutExpired:  # say what the run printed after the signal, not only that it timed out
            proc.kill()
            rest, _ = proc.communicate()
            pytest.fail("the run did not stop within 180 s of SIGTERM; its output:\n" + "".join(seen) + rest)
    finally:
        if proc.poll() is None:
            proc.kill()
    out = "".join(seen) + rest
    assert proc.returncode == EXIT_INTERRUPTED, out
    assert "interrupted — finished units are kept" in out
    assert "INFO mlflow" not in out  # a fresh work dir's store creation is not chatter on the console

    def running(pid: int) -> bool:  # not ended and not a zombie; it may end while it is read
        try:
            return "Z" not in Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            return False

    def alive() -> list[int]:
        return [pid for pid in helpers if running(pid)]

    deadline = time.monotonic() + 30  # a loaded machine may take a few seconds to reap them
    while alive() and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not alive(), f"helper processes left running: {alive()}"


def test_a_second_interrupt_stops_at_once_and_terminates_the_children():
    """A unit running in a worker thread cannot be interrupted, so the first Ctrl-C / SIGTERM unwinds the main
    thread (KeyboardInterrupt) and the second one terminates the child processes and exits 130 at once."""
    import io
    import signal

    from flows.cli import EXIT_INTERRUPTED, Interrupts

    exits, stream = [], io.StringIO()
    stopper = Interrupts(exit=exits.append, children=lambda: [2 ** 22 + 12345], stream=stream)  # no such pid
    with pytest.raises(KeyboardInterrupt):
        stopper.handle(signal.SIGTERM, None)
    assert exits == [] and "press Ctrl-C again" in stream.getvalue()
    stopper.handle(signal.SIGINT, None)  # the unknown child pid is skipped quietly
    assert exits == [EXIT_INTERRUPTED] and "finished units are kept" in stream.getvalue()


def test_child_pids_finds_a_child_process():
    import subprocess
    import sys

    from flows.cli import _child_pids

    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        assert child.pid in _child_pids()
    finally:
        child.kill()
        child.wait()


def test_prefect_database_is_prepared_once_under_a_lock_and_then_skipped(tmp_path, monkeypatch):
    import subprocess

    import flows.runtime

    monkeypatch.setenv("PREFECT_HOME", str(tmp_path / "home"))
    monkeypatch.delenv("PREFECT_API_URL", raising=False)
    monkeypatch.delenv("PREFECT_API_DATABASE_CONNECTION_URL", raising=False)
    from prefect.context import refresh_global_settings_context

    refresh_global_settings_context()
    try:
        database = flows.runtime._local_prefect_database()
        assert database == tmp_path / "home" / "prefect.db" and not database.exists()
        flows.runtime.prepare_prefect_database(tmp_path)
        assert database.is_file() and list(database.parent.glob(".multigrasp-prepared-*"))
        memo = database.parent / "memo_store.toml"  # Prefect's record that the block types are registered
        assert "block_auto_registration" in memo.read_text()

        def no_second_server(*args, **kwargs):
            raise AssertionError("a second server was started for a prepared database")

        monkeypatch.setattr(subprocess, "Popen", no_second_server)
        flows.runtime.prepare_prefect_database(tmp_path)
        monkeypatch.setenv("PREFECT_API_URL", "http://127.0.0.1:4242/api")  # a server of the user's: not ours to touch
        assert flows.runtime._local_prefect_database() is None
    finally:
        monkeypatch.undo()
        refresh_global_settings_context()

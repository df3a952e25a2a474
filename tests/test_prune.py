"""``multigrasp prune``: what a kept config uses stays (and is served from cache after), the rest goes; nothing is
deleted under a running invocation or where a kept config's upstream is unfinished."""

from __future__ import annotations

import os
import threading
import time

import pytest

from flows.cli import main
from flows.config import load_config
from flows.pipeline import status
from tasks.artifacts import lock_path, workdir_exclusive, workdir_in_use
from tasks.units import executions, records_dir

pytestmark = pytest.mark.slow

# The scenes stage alone, small (as tests/test_flows.py): 8 single-object jobs; KEPT in 2 shards, OTHER in 4.
SMALL = ["scenes.pairs=false", "scenes.many=false", "scenes.renders=1",
         "scenes.per_combination={train: 1, Pl: 0, Com: 0, Geo: 0, many: 0}"]
KEPT = SMALL + ["scenes.jobs_per_shard=4"]
OTHER = SMALL + ["scenes.jobs_per_shard=2"]


def _argv(command: str, workdir, sets, *extra: str) -> list[str]:
    return [command, "--profile", "smoke", "--workdir", str(workdir), *sum([["--set", s] for s in sets], []), *extra]


@pytest.fixture()
def two_configs(tmp_path):
    """A work dir holding the scenes of two configs (KEPT, then OTHER)."""
    assert main(_argv("run", tmp_path, KEPT, "--until", "scenes")) == 0
    assert main(_argv("run", tmp_path, OTHER, "--until", "scenes")) == 0
    return tmp_path


def _folders(workdir, stage="scenes") -> set[str]:
    folder = workdir / "stages" / stage
    return {p.name for p in folder.iterdir()} if folder.is_dir() else set()


def test_prune_lists_then_deletes_only_what_no_kept_config_uses(two_configs, capsys):
    workdir = two_configs
    kept_cfg, other_cfg = (load_config("smoke", sets=s, workdir=workdir) for s in (KEPT, OTHER))
    before = _folders(workdir)
    assert len(before) == 3 + 5  # 2 shards + merge, 4 shards + merge

    assert main(_argv("prune", workdir, KEPT)) == 0  # a dry run
    out = capsys.readouterr().out
    assert "would delete 5 folder(s)" in out and "5 other config" in out and "--yes" in out
    assert _folders(workdir) == before

    assert main(_argv("prune", workdir, KEPT, "--yes")) == 0
    assert "deleted 5 folder(s)" in capsys.readouterr().out
    kept = _folders(workdir)
    assert len(kept) == 3
    assert {r.name: r.state for r in status(kept_cfg)}["scenes"] == "done"
    assert {r.name: r.state for r in status(other_cfg)}["scenes"] == "stale"  # only the kept config's are left
    # the deleted units' Prefect records and lock files went with them; the kept ones' stayed
    assert {p.name for p in records_dir(workdir).iterdir()} == kept
    assert not any(lock_path(workdir, key).exists() for key in before - kept)
    # the kept config is served from cache, nothing recomputed
    computed = executions(workdir)
    assert main(_argv("run", workdir, KEPT, "--until", "scenes")) == 0
    assert executions(workdir) == computed

    assert main(_argv("prune", workdir, KEPT + ["scenes.renders=1"], "--keep", "smoke")) == 0
    assert "nothing to delete" in capsys.readouterr().out


def test_prune_keeps_a_kept_configs_unfinished_units_and_every_config_named(two_configs, capsys):
    workdir = two_configs
    yaml = workdir.parent / "other.yaml"
    yaml.write_text("scenes:\n  pairs: false\n  many: false\n  renders: 1\n  jobs_per_shard: 2\n"
                    "  per_combination: {train: 1, Pl: 0, Com: 0, Geo: 0, many: 0}\n")
    assert main(_argv("prune", workdir, KEPT, "--keep", f"smoke:{yaml}", "--yes")) == 0
    assert len(_folders(workdir)) == 8  # both configs named: nothing goes

    import flows.scenes

    kept_cfg = load_config("smoke", sets=KEPT, workdir=workdir)
    # an interrupted unit of the kept config (its checkpoint would resume a training) stays; one of no config goes
    merge = flows.scenes.planned_units(kept_cfg, {})[-1]
    (merge.folder / "manifest.json").unlink()
    stray = workdir / "stages" / "scenes" / "0123456789abcdef0123"
    stray.mkdir()
    (stray / "checkpoint.pt").write_bytes(b"x")
    # while the kept config's scenes stage is partial, the stages after it cannot tell current from stale: kept whole
    later = workdir / "stages" / "synthesize" / "fedcba9876543210fedc"
    later.mkdir(parents=True)
    (later / "grasps.parquet").write_bytes(b"x")
    assert main(_argv("prune", workdir, KEPT, "--yes")) == 0
    out = capsys.readouterr().out
    assert "1 unfinished" in out and "all kept: scenes is partial or corrupt" in out
    assert merge.folder.is_dir() and not stray.exists() and later.exists()


def test_prune_deletes_nothing_while_an_invocation_uses_the_work_dir(two_configs, capsys):
    workdir = two_configs
    before = _folders(workdir)
    with workdir_in_use(workdir):  # a run / evaluate / generate holds it shared for its whole length
        assert main(_argv("prune", workdir, KEPT, "--yes")) == 2
    err = capsys.readouterr().err
    assert f"an invocation is using {workdir} now (pid {os.getpid()} (" in err and "nothing was deleted" in err
    assert _folders(workdir) == before


def test_prune_needs_the_configs_named_and_a_work_dir(tmp_path, capsys):
    assert main(["prune", "--workdir", str(tmp_path)]) == 2
    assert "pass --profile" in capsys.readouterr().err
    assert main(["prune", "--profile", "smoke", "--workdir", str(tmp_path / "nowhere")]) == 2
    assert "no work dir at" in capsys.readouterr().err
    assert not (tmp_path / "nowhere").exists()


def test_an_invocation_waits_for_a_running_prune(tmp_path):
    events = []

    def invocation():
        with workdir_in_use(tmp_path, on_wait=lambda: events.append("waiting")):
            events.append("running")

    with workdir_exclusive(tmp_path) as users:
        assert users is None
        worker = threading.Thread(target=invocation)
        worker.start()
        deadline = time.monotonic() + 30  # however slowly the worker thread is scheduled
        while not events and time.monotonic() < deadline:
            time.sleep(0.02)
        time.sleep(0.2)  # had it not waited, it would have run by now
        assert events == ["waiting"]
    worker.join(timeout=10)
    assert events == ["waiting", "running"]
    assert not list((tmp_path / "locks" / "invocations").iterdir())  # its record goes with it


@pytest.mark.parametrize("jobs", ["specialists", "generalist"])
def test_prune_deletes_the_lift_jobs_of_older_code_and_unfinished_ones_only(tmp_path, jobs):
    """Lift jobs (tasks/lift_jobs.py, tasks/generalist_jobs.py) are not planned by a config: finished ones of this
    code stay, whatever config made them; those of another code version, or without a manifest (interrupted), go."""
    from flows.prune import PrunePlan, _plan_lift_jobs
    from tasks import generalist_jobs, lift_jobs
    from tasks.artifacts import atomic_write_json, code_version, write_manifest

    STAGE, code_now = ((lift_jobs.STAGE, code_version(*lift_jobs.LIFT_CODE)) if jobs == "specialists" else
                       (generalist_jobs.STAGE, code_version(*generalist_jobs.GENERALIST_LIFT_CODE)))
    stage_dir = tmp_path / "stages" / STAGE
    for name, code in (("aaaa", code_now), ("bbbb", "0ld"), ("cccc", None)):
        folder = stage_dir / name
        result = atomic_write_json(folder / "result.json", {"policy": [1], "wo_rl": None, "squeeze": None, "gifs": []})
        if code is not None:
            write_manifest(stage=STAGE, unit="lift-cube-0", key=name, folder=folder, files={"result": result}, code=code)
    plan = PrunePlan(workdir=tmp_path, kept=["smoke"])
    _plan_lift_jobs(stage_dir, plan)
    assert {c.key: c.reason for c in plan.candidates} == {"bbbb": "older code", "cccc": "unfinished"}
    assert plan.kept_units == {STAGE: 1}

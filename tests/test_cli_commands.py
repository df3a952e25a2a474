"""Single-stage commands (DESIGN §1: ``multigrasp synthesize|train-generator|train-lifting|…``): each runs its stage
after the upstream stages it needs, and nothing else."""

from __future__ import annotations

import pytest

import flows.pipeline
from components.errors import MultigraspError
from flows.cli import main
from flows.pipeline import with_upstream


def test_a_stage_with_its_upstream_in_execution_order():
    assert with_upstream("scenes") == ["scenes"]
    assert with_upstream("pointnet") == ["pointnet"]
    assert with_upstream("train-generator") == ["scenes", "synthesize", "train-generator"]
    assert with_upstream("specialists") == ["scenes", "synthesize", "pointnet", "specialists"]
    assert with_upstream("reach") == ["scenes", "synthesize", "reach"]
    with pytest.raises(MultigraspError, match="unknown stage 'lift'"):
        with_upstream("lift")


@pytest.mark.parametrize("command, stages", [
    ("synthesize", ["scenes", "synthesize"]),
    ("train-generator", ["scenes", "synthesize", "train-generator"]),
    ("pointnet", ["pointnet"]),
    ("train-lifting", ["scenes", "synthesize", "pointnet", "specialists"]),
    ("specialists", ["scenes", "synthesize", "pointnet", "specialists"]),
    ("reach", ["scenes", "synthesize", "reach"]),
])
def test_each_single_stage_command_runs_its_stage_after_its_upstream(command, stages, tmp_path, monkeypatch, capsys):
    ran = {}

    def fake_run_pipeline(cfg, modules, command):
        ran.update(stages=[m.STAGE for m in modules], command=command)
        raise MultigraspError("recorded")

    monkeypatch.setattr(flows.pipeline, "run_pipeline", fake_run_pipeline)
    assert main([command, "--workdir", str(tmp_path)]) == 2
    assert ran["stages"] == stages and ran["command"] in (command, "train-lifting")
    assert "error: recorded" in capsys.readouterr().err


def test_generate_objects_may_be_written_with_spaces_after_the_commas():
    """``--objects "cube, cylinder"`` named an unknown object ' cylinder'."""
    from flows.cli import build_parser

    assert build_parser().parse_args(["generate", "--objects", "cube, cylinder ,"]).objects == ["cube", "cylinder"]


def test_a_work_dir_that_cannot_be_made_is_one_line(tmp_path, capsys):
    """``--workdir`` under a file (or on a read-only mount) ended in an OSError traceback from the work dir's lock."""
    (tmp_path / "afile").write_text("")
    assert main(["run", "--profile", "smoke", "--workdir", str(tmp_path / "afile" / "runs")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "cannot use the work dir" in err and "pass --workdir a folder you can write" in err

"""A command that asks for CUDA where torch cannot reach a GPU stops with one line, before any stage runs."""

import pytest
import torch

import components.device as device
from components.errors import MultigraspError
from flows.cli import main


def test_cpu_is_always_usable():
    assert device.require_device("cpu") == torch.device("cpu")


def test_cuda_problem_names_a_cpu_only_build_and_a_missing_device(monkeypatch):
    monkeypatch.setattr(torch.backends.cuda, "is_built", lambda: False)
    assert "CPU-only build" in device.cuda_problem()
    monkeypatch.setattr(torch.backends.cuda, "is_built", lambda: True)
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert "sees no CUDA device" in device.cuda_problem()
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    assert device.cuda_problem() is None


def test_require_cuda_without_a_gpu_names_the_option_and_the_fix(monkeypatch):
    monkeypatch.setattr(device, "cuda_problem", lambda: "this torch (x) is a CPU-only build")
    with pytest.raises(MultigraspError, match=r"^--device is cuda but this torch \(x\) is a CPU-only build — use "
                                              r"--device cpu, or install a CUDA build of torch first \(README 'On a GPU'\)$"):
        device.require_device("cuda")


@pytest.mark.parametrize("argv, source", [
    (["run", "--profile", "smoke", "--device", "cuda"], "--device"),
    (["run", "--profile", "paper"], "run.device of profile 'paper'"),  # the paper profile asks for cuda
    (["run", "--profile", "smoke", "--set", "run.device=cuda"], "run.device of profile 'smoke'"),
    (["evaluate", "pregrasp", "--source", "synthetic", "--device", "cuda"], "--device"),
    (["generate", "--objects", "cube,cylinder", "--device", "cuda"], "--device"),
    (["bench", "synthesis", "--device", "cuda", "--json", "OUT"], "--device"),
])
def test_commands_asking_for_cuda_stop_in_one_line_before_any_work(tmp_path, monkeypatch, capsys, argv, source):
    monkeypatch.setattr(device, "cuda_problem", lambda: "this torch (x) is a CPU-only build")
    workdir = tmp_path / "runs"
    argv = [str(tmp_path / "out.json") if a == "OUT" else a for a in argv]
    if argv[0] != "bench":
        argv += ["--workdir", str(workdir)]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {source}") and "is cuda but this torch (x) is a CPU-only" in err[0]
    assert not workdir.exists() and not (tmp_path / "out.json").exists()


def test_status_reads_a_cuda_profile_without_a_gpu(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(device, "cuda_problem", lambda: "this torch (x) is a CPU-only build")
    assert main(["status", "--profile", "paper", "--workdir", str(tmp_path / "runs")]) == 0
    assert "scenes" in capsys.readouterr().out

"""The embedded MLflow store follows its work dir when the work dir is moved or copied."""

from __future__ import annotations

import shutil

from tasks.tracking import Tracker, artifact_root, default_tracking_uri, relocate_embedded_store


def _store_with_one_artifact(workdir):
    tracker = Tracker(default_tracking_uri(workdir), "relocation", workdir)
    run = tracker.start_run("stage")
    tracker.log_text(run, "hello", "notes/hello.txt")
    tracker.end_run(run)
    return run


def test_a_copied_store_is_rewritten_to_its_own_artifacts_and_left_alone_after(tmp_path, monkeypatch):
    from mlflow.tracking import MlflowClient

    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    run = _store_with_one_artifact(tmp_path / "cluster")
    shutil.copytree(tmp_path / "cluster", tmp_path / "laptop")
    shutil.rmtree(tmp_path / "cluster")
    laptop = tmp_path / "laptop"
    assert relocate_embedded_store(laptop) == artifact_root(tmp_path / "cluster")
    assert relocate_embedded_store(laptop) is None  # nothing left to move
    client = MlflowClient(default_tracking_uri(laptop))
    assert client.get_run(run).info.artifact_uri == artifact_root(laptop) + f"/{run}/artifacts"
    assert [a.path for a in client.list_artifacts(run, "notes")] == ["notes/hello.txt"]
    assert client.get_experiment_by_name("relocation").artifact_location == artifact_root(laptop)


def test_a_store_named_by_the_environment_is_never_rewritten(tmp_path, monkeypatch):
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    _store_with_one_artifact(tmp_path / "a")
    shutil.copytree(tmp_path / "a", tmp_path / "b")
    monkeypatch.setenv("MLFLOW_TRACKING_URI", "sqlite:///" + str(tmp_path / "b" / "mlflow.db"))
    assert relocate_embedded_store(tmp_path / "b") is None
    assert relocate_embedded_store(tmp_path / "missing") is None


def test_provenance_names_the_commit_and_uncommitted_changes_of_a_checkout(tmp_path, capsys, monkeypatch):
    import subprocess

    from flows.cli import main
    from tasks.tracking import provenance_tags, version_line

    monkeypatch.delenv("MULTIGRASP_GIT_COMMIT", raising=False)
    outside = provenance_tags(tmp_path)  # an installation outside a git checkout: no git tags
    assert "mlflow.source.git.commit" not in outside and outside["multigrasp.torch"]
    monkeypatch.setenv("MULTIGRASP_GIT_COMMIT", "abc123")  # unless its builder recorded the commit (docker image)
    assert provenance_tags(tmp_path)["mlflow.source.git.commit"] == "abc123"
    git = ["git", "-C", str(tmp_path), "-c", "user.name=t", "-c", "user.email=t@t"]
    subprocess.run([*git, "init", "-q"], check=True)
    (tmp_path / "a.txt").write_text("1")
    subprocess.run([*git, "add", "a.txt"], check=True)
    subprocess.run([*git, "commit", "-qm", "c"], check=True)
    head = subprocess.run([*git, "rev-parse", "HEAD"], capture_output=True, text=True, check=True).stdout.strip()
    clean = provenance_tags(tmp_path)
    assert clean["mlflow.source.git.commit"] == head and clean["multigrasp.git_dirty"] == "false"
    (tmp_path / "new.txt").write_text("untracked files do not count")
    assert provenance_tags(tmp_path)["multigrasp.git_dirty"] == "false"
    (tmp_path / "a.txt").write_text("2")
    assert provenance_tags(tmp_path)["multigrasp.git_dirty"] == "true"
    assert version_line(tmp_path).startswith(f"multigrasp {clean['multigrasp.version']} (git {head[:12]}, "
                                             "uncommitted changes), torch ")
    import pytest

    with pytest.raises(SystemExit) as exited:
        main(["--version"])
    assert exited.value.code == 0
    assert capsys.readouterr().out.startswith("multigrasp ")

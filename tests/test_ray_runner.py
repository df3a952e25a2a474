"""The Ray runner's session: one Ray per invocation, with this run's Prefect settings handed to its workers.

CI does not install Ray (`pip install 'multigrasp[ray]'`), so a stand-in module records what the session asks of
Ray; README "Work directory, caching and resume" gives the measured end-to-end run with the real one."""

from __future__ import annotations

import sys
import types

import pytest

from flows.config import load_config
from flows.runtime import RAY_WORKER_ENV, needs_run_server, ray_session
from tests.standins import FakeRay


def _run(tmp_path, *sets):
    return load_config("smoke", None, ["run.runner=ray", *sets], workdir=tmp_path).run


def test_a_local_ray_gets_the_runs_prefect_server_and_a_cluster_does_not(tmp_path):
    assert needs_run_server(_run(tmp_path))
    assert not needs_run_server(_run(tmp_path, "run.ray_address=ray://head:10001"))
    assert needs_run_server(load_config("smoke", None, ["run.runner=processes"], workdir=tmp_path).run)
    assert not needs_run_server(load_config("smoke", None, [], workdir=tmp_path).run)


def test_one_ray_per_invocation_with_the_runs_prefect_settings(tmp_path, monkeypatch):
    fake = FakeRay()
    monkeypatch.setitem(sys.modules, "ray", fake)
    monkeypatch.setitem(sys.modules, "prefect_ray", types.ModuleType("prefect_ray"))
    for name in RAY_WORKER_ENV:
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("PREFECT_API_URL", "http://127.0.0.1:4242/api")
    with ray_session(_run(tmp_path), tmp_path / "prefect"):
        assert fake.initialized
    (init, kwargs), (shutdown, _) = fake.calls
    assert (init, shutdown) == ("init", "shutdown")
    assert kwargs["address"] is None and kwargs["include_dashboard"] is False
    assert kwargs["runtime_env"]["env_vars"] == {"PREFECT_API_URL": "http://127.0.0.1:4242/api",
                                                 "PREFECT_LOCAL_STORAGE_PATH": str(tmp_path / "prefect")}


def test_a_cluster_address_is_joined_without_local_only_options(tmp_path, monkeypatch):
    fake = FakeRay()
    monkeypatch.setitem(sys.modules, "ray", fake)
    monkeypatch.setitem(sys.modules, "prefect_ray", types.ModuleType("prefect_ray"))
    with ray_session(_run(tmp_path, "run.ray_address=ray://head:10001"), tmp_path):
        pass
    assert fake.calls[0][1]["address"] == "ray://head:10001" and "include_dashboard" not in fake.calls[0][1]


def test_a_ray_the_caller_started_is_used_and_left_running(tmp_path, monkeypatch):
    fake = FakeRay(initialized=True)
    monkeypatch.setitem(sys.modules, "ray", fake)
    monkeypatch.setitem(sys.modules, "prefect_ray", types.ModuleType("prefect_ray"))
    with ray_session(_run(tmp_path), tmp_path):
        pass
    assert fake.calls == [] and fake.initialized


def test_without_ray_installed_the_session_names_the_extra(tmp_path, monkeypatch):
    from components.errors import MultigraspError

    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError
    with pytest.raises(MultigraspError, match=r"pip install 'multigrasp\[ray\]'"):
        with ray_session(_run(tmp_path), tmp_path):
            pass
    monkeypatch.setitem(sys.modules, "ray", FakeRay())  # Ray without prefect-ray: caught before any stage too
    monkeypatch.setitem(sys.modules, "prefect_ray", None)
    with pytest.raises(MultigraspError, match=r"needs prefect-ray"):
        with ray_session(_run(tmp_path), tmp_path):
            pass

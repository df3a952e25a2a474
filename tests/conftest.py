"""Shared fixtures. A test module that defines a fixture of the same name overrides these."""

import pytest
import torch

from components.hand import HandConfig, HandModel
from components.objects import ObjectLibrary, ObjectsConfig


@pytest.fixture(scope="session", autouse=True)
def prefect_database(tmp_path_factory):
    """Prefect's local database set up before any test, so that no test's captured output holds the one-time
    "setting up Prefect's local database" line (a fresh CI clone has no ``~/.prefect``; the workers of ``make test``
    take turns under the lock).  ``tests/test_resume.py`` checks the setting-up itself on fresh homes."""
    from flows.runtime import prefect_defaults, prepare_prefect_database

    prefect_defaults()
    prepare_prefect_database(tmp_path_factory.getbasetemp())


@pytest.fixture(scope="session")
def hand():
    """The Shadow Hand in float64 (analytic checks want the precision)."""
    return HandModel(HandConfig(), dtype=torch.float64)


@pytest.fixture(scope="session")
def library(tmp_path_factory):
    """A small library (cube, cylinder, sphere) with a session-wide cache."""
    return ObjectLibrary(ObjectsConfig(train=["cube", "cylinder", "sphere"], ood=[]),
                         tmp_path_factory.getbasetemp() / "objects-cache")

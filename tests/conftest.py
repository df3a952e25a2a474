"""Shared fixtures. A test module that defines a fixture of the same name overrides these."""

import pytest
import torch

from components.hand import HandConfig, HandModel
from components.objects import ObjectLibrary, ObjectsConfig


@pytest.fixture(scope="session")
def hand():
    """The Shadow Hand in float64 (analytic checks want the precision)."""
    return HandModel(HandConfig(), dtype=torch.float64)


@pytest.fixture(scope="session")
def library(tmp_path_factory):
    """A small library (cube, cylinder, sphere) with a session-wide cache."""
    return ObjectLibrary(ObjectsConfig(train=["cube", "cylinder", "sphere"], ood=[]),
                         tmp_path_factory.getbasetemp() / "objects-cache")

"""Fail fast: validate user inputs before any flow starts.

Object names, user meshes (missing, not a mesh, open, too large for the hand) are checked
by building the object library once, in the work dir's cache — the same cache every unit
uses, so nothing is computed twice.  A problem raises a one-line ``MultigraspError``
before any work starts, so a typo never costs a half-run pipeline.
"""

from __future__ import annotations

from pathlib import Path


def cache_dir(workdir: Path) -> Path:
    """Component caches (SDF grids, convex pieces, resting poses, the hand URDF)."""
    return Path(workdir) / "cache"


def validate_inputs(objects_cfg, hand_cfg, workdir: Path) -> None:
    """Build the object library and the hand model once; raises MultigraspError on bad input."""
    from components.hand import HandModel
    from components.objects import ObjectLibrary

    ObjectLibrary(objects_cfg, cache_dir=cache_dir(workdir))
    HandModel(hand_cfg)

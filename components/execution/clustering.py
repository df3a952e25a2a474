"""Specialist bins (paper §"Learning a Generalist from Specialists").

A bin groups pre-grasps one specialist policy learns.  The paper bins by object combination, each
subdivided by the direction of the line joining the object centres in the palm frame (6 bins).  With
y the palm normal of the palm frame, that line's direction in the palm plane (x-z) is

    theta = atan2(d_z, d_x) mod pi,   d = R_palm^T (c_2 - c_1)   (a line: theta and theta + pi are one),

and the placement bin is floor(theta / (pi / placement_bins)).  With more than two objects d is the
principal axis of their centres; a single object has placement bin 0.  Modes (the paper's ablations):
``combination_placement`` (ours), ``placement`` (w/o Spe-Com: placement only), ``combination``
(w/o Spe-Pl: combination only), ``single`` (w/o Spe: one bin).
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from pydantic import Field

from components.config_base import Section
from components.execution.lift_sim import GraspRecord


class ClusteringConfig(Section):
    """How pre-grasps are split among specialists."""

    mode: Literal["combination_placement", "placement", "combination", "single"] = Field(
        "combination_placement",
        description="combination_placement: per object combination and placement direction (paper); placement: "
        "direction only ('w/o Spe-Com'); combination: combination only ('w/o Spe-Pl'); single: one bin ('w/o Spe').")
    placement_bins: int = Field(6, ge=1, description="Sectors of the centre-line direction over [0, pi) (paper: 6).")


def centre_line_angle(record: GraspRecord) -> float:
    """theta of the module docstring (rad, in [0, pi)); 0 for a single object."""
    centres = np.array([pl.position for pl in record.scene.objects], dtype=float)
    if len(centres) < 2:
        return 0.0
    if len(centres) == 2:
        d = centres[1] - centres[0]
    else:
        _, _, vt = np.linalg.svd(centres - centres.mean(0))
        d = vt[0]
    local = np.asarray(record.R, float).T @ d
    return math.atan2(local[2], local[0]) % math.pi


def placement_bin(record: GraspRecord, bins: int) -> int:
    return min(int(centre_line_angle(record) / (math.pi / bins)), bins - 1)


def bin_label(record: GraspRecord, cfg: ClusteringConfig) -> str:
    """The record's bin: '<a+b>/<k>', '<a+b>', '<n>obj/placement-<k>' or '<n>obj' by ``cfg.mode``.  Bins
    never mix object counts (one policy's observation size depends on it)."""
    combo = "+".join(sorted(record.scene.names))
    count = f"{len(record.scene.objects)}obj"
    if cfg.mode == "single":
        return count
    if cfg.mode == "combination":
        return combo
    k = placement_bin(record, cfg.placement_bins)
    return f"{count}/placement-{k}" if cfg.mode == "placement" else f"{combo}/{k}"


def assign_bins(records: list[GraspRecord], cfg: ClusteringConfig) -> dict[str, list[int]]:
    """Bin label -> indices of its records (labels sorted)."""
    out: dict[str, list[int]] = {}
    for i, record in enumerate(records):
        out.setdefault(bin_label(record, cfg), []).append(i)
    return dict(sorted(out.items()))

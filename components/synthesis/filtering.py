"""The filter that keeps synthesised grasps of good quality (paper §"Preliminaries"; DESIGN §5.1).

A grasp is accepted when every criterion holds (thresholds from :class:`SynthesisConfig`, official values):

* ``fc``:               max over objects of E_fc < ``filter_fc`` (0.25)
* ``contact_distance``: max over objects of the mean |d_O(c)| of the object's contacts <
  ``filter_contact_distance_m`` (5 mm), as the official release -- or, with
  ``filter_contact_distance_reduce='max'``, every contact within it (stricter)
* ``penetration``:      the deepest sampled penetration -- object points in the hand, hand points in the
  objects, hand below the table, hand self-penetration -- < ``filter_penetration_m`` (5 mm)
* ``prior``:            E_prior (rad beyond the joint limits) < ``filter_prior`` (0.1)

Rows with a non-finite energy are rejected as ``non_finite``.  The reason of a rejected row is its
first failing criterion in the order above.
"""

from __future__ import annotations

from collections import Counter

import torch
from torch import Tensor

from components.synthesis.config import SynthesisConfig

#: Rejection reasons in the order they are checked; accepted rows get ``ACCEPTED``.
FILTER_REASONS = ("non_finite", "fc", "contact_distance", "penetration", "prior")
ACCEPTED = "accepted"


def contact_distance_for_filter(terms: dict, cfg: SynthesisConfig) -> Tensor:
    """The distance the contact criterion tests (B,): the largest |d_O| over all contacts
    (``filter_contact_distance_reduce='max'``) or the largest over objects of the mean |d_O| of the object's
    contacts (``'mean'``, the official ``surf_dist.mean(-1).max(-1)``)."""
    if cfg.filter_contact_distance_reduce == "mean":
        return terms["contact_distance_per_object"].amax(-1)
    return terms["contact_distance_max"]


def filter_checks(terms: dict, cfg: SynthesisConfig) -> dict[str, Tensor]:
    """Per criterion, the rows that FAIL it (B,) bool (module docstring)."""
    finite = torch.ones_like(terms["prior"], dtype=torch.bool)
    for value in terms.values():
        finite &= torch.isfinite(value.reshape(value.shape[0], -1)).all(-1)
    return {
        "non_finite": ~finite,
        "fc": ~(terms["fc_per_object"].amax(-1) < cfg.filter_fc),
        "contact_distance": ~(contact_distance_for_filter(terms, cfg) < cfg.filter_contact_distance_m),
        "penetration": ~(terms["penetration_depth_max"] < cfg.filter_penetration_m),
        "prior": ~(terms["prior"] < cfg.filter_prior),
    }


def filter_grasps(terms: dict, cfg: SynthesisConfig) -> tuple[Tensor, list[str]]:
    """Accept mask (B,) and, per row, ``"accepted"`` or the first failing reason of ``FILTER_REASONS``."""
    failed = filter_checks(terms, cfg)
    stacked = torch.stack([failed[r] for r in FILTER_REASONS], dim=-1)  # (B, n_reasons)
    accepted = ~stacked.any(-1)
    first = stacked.float().argmax(-1)  # first failing criterion (argmax returns the first maximum)
    reasons = [ACCEPTED if ok else FILTER_REASONS[int(i)] for ok, i in zip(accepted.tolist(), first.tolist())]
    return accepted, reasons


def count_reasons(reasons: list[str]) -> dict[str, int]:
    """How many rows got each reason (every reason present, zeros included)."""
    counts = Counter(reasons)
    return {r: counts.get(r, 0) for r in (ACCEPTED, *FILTER_REASONS)}

"""Evaluation splits of object combinations (paper §Experiments, "Evaluation protocol").

The paper: "the 8 objects in our dataset result in C(8,1) + C(8,2) = 36 unique combinations.
We designate 8 pairs as unseen combinations, covering all objects ... Further, 6 combinations
with 3 out-of-domain objects are introduced". Our choices where the paper is silent:

* ``Com`` (held-out pairs): the consecutive pairs of the ``train`` list taken cyclically,
  ``(o0, o1), (o1, o2), ..., (o7, o0)`` — deterministic, covers every object exactly twice,
  so each object keeps 5 of its 7 pairs for training (none loses more than another). With
  fewer than 4 training objects the cycle would hold out most pairs, so only the pair
  ``(o_last, o0)`` is held out for 3 objects and none for 1-2. ``ObjectsConfig.heldout_pairs``
  overrides the rule.
* ``Geo``: the 3 OOD singles + their 3 pairs = C(3,1) + C(3,2) = 6, the same "singles +
  pairs" construction as the training set, on unseen geometry only.
* ``train``: the 36 combinations minus ``Com``: 8 singles + 20 pairs = 28.
* ``Pl``: the same combinations as ``train`` — evaluated on *unseen placements* (scenes
  sampled with another seed than the training data).
* ``many``: ``many_object`` repeated ``many_counts`` times (3, 4, 5 small cylinders).

Every list is sorted in config order and deterministic.
"""

from __future__ import annotations

import itertools

from components.objects.config import ObjectsConfig

Combination = tuple[str, ...]
SPLIT_KEYS = ("train", "Pl", "Com", "Geo", "many")
#: Below this many training objects, the cyclic held-out rule would leave too few training pairs.
MIN_OBJECTS_FOR_CYCLIC_HOLDOUT = 4


def _pairs(names: list[str]) -> list[Combination]:
    """All unordered pairs, in config order: C(n, 2)."""
    return [tuple(p) for p in itertools.combinations(names, 2)]


def _canonical(pair: tuple[str, str], order: list[str]) -> Combination:
    """A pair with its members in config order (so (b, a) and (a, b) are the same combination)."""
    return tuple(sorted(pair, key=order.index))


def heldout_pairs(cfg: ObjectsConfig) -> list[Combination]:
    """Training pairs held out as unseen combinations (``Com``); see the module docstring."""
    names = list(cfg.train)
    if cfg.heldout_pairs is not None:
        return [_canonical(p, names) for p in cfg.heldout_pairs]
    n = len(names)
    if n >= MIN_OBJECTS_FOR_CYCLIC_HOLDOUT:
        return [_canonical((names[i], names[(i + 1) % n]), names) for i in range(n)]
    if n == MIN_OBJECTS_FOR_CYCLIC_HOLDOUT - 1:
        return [_canonical((names[-1], names[0]), names)]
    return []


def combinations(
    objects_cfg: ObjectsConfig,
    include_singles: bool = True,
    include_pairs: bool = True,
    include_many: bool = True,
) -> dict[str, list[Combination]]:
    """The evaluation splits: ``{"train", "Pl", "Com", "Geo", "many"}`` -> list of name tuples.

    ``include_singles`` / ``include_pairs`` filter every split by size; ``include_many=False``
    leaves ``many`` empty. Held-out pairs are never in ``train`` / ``Pl``.
    """
    train_names, ood_names = list(objects_cfg.train), list(objects_cfg.ood)
    held = heldout_pairs(objects_cfg)
    seen: list[Combination] = []
    if include_singles:
        seen += [(n,) for n in train_names]
    if include_pairs:
        seen += [p for p in _pairs(train_names) if p not in held]
    geo: list[Combination] = []
    if include_singles:
        geo += [(n,) for n in ood_names]
    if include_pairs:
        geo += _pairs(ood_names)
    many = [(objects_cfg.many_object,) * k for k in objects_cfg.many_counts] if include_many else []
    return {
        "train": list(seen),
        "Pl": list(seen),
        "Com": list(held) if include_pairs else [],
        "Geo": geo,
        "many": many,
    }

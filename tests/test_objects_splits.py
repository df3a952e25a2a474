"""Evaluation splits (paper §Experiments): 36 combinations, 8 held-out pairs, 6 OOD combinations."""

from __future__ import annotations

import itertools

from components.objects import DEFAULT_OOD_OBJECTS, DEFAULT_TRAIN_OBJECTS, SPLIT_KEYS, ObjectsConfig, combinations


def test_eight_objects_give_36_combinations_and_8_heldout_pairs_cover_all_objects():
    splits = combinations(ObjectsConfig())
    assert set(splits) == set(SPLIT_KEYS)
    singles = [c for c in splits["train"] if len(c) == 1]
    pairs = [c for c in splits["train"] if len(c) == 2]
    assert len(singles) == 8 and len(pairs) + len(splits["Com"]) == 28
    assert len(singles) + len(pairs) + len(splits["Com"]) == 36
    assert len(splits["Com"]) == 8 and all(len(c) == 2 for c in splits["Com"])
    assert {n for c in splits["Com"] for n in c} == set(DEFAULT_TRAIN_OBJECTS)
    assert not set(splits["Com"]) & set(splits["train"])  # held-out pairs are never trained on
    all_pairs = {tuple(sorted(p)) for p in itertools.combinations(DEFAULT_TRAIN_OBJECTS, 2)}
    assert {tuple(sorted(c)) for c in pairs + splits["Com"]} == all_pairs


def test_every_object_keeps_training_pairs():
    splits = combinations(ObjectsConfig())
    for name in DEFAULT_TRAIN_OBJECTS:
        assert sum(name in c for c in splits["train"] if len(c) == 2) == 5


def test_geo_has_6_combinations_of_the_3_ood_objects():
    geo = combinations(ObjectsConfig())["Geo"]
    assert len(geo) == 6
    assert {n for c in geo for n in c} == set(DEFAULT_OOD_OBJECTS)
    assert sorted(len(c) for c in geo) == [1, 1, 1, 2, 2, 2]


def test_pl_is_the_seen_combinations_and_many_is_3_to_5_small_cylinders():
    splits = combinations(ObjectsConfig())
    assert splits["Pl"] == splits["train"]
    assert splits["many"] == [("small_cylinder",) * 3, ("small_cylinder",) * 4, ("small_cylinder",) * 5]


def test_splits_are_deterministic():
    assert combinations(ObjectsConfig()) == combinations(ObjectsConfig())


def test_filters_and_overrides():
    only_pairs = combinations(ObjectsConfig(), include_singles=False, include_many=False)
    assert all(len(c) == 2 for key in ("train", "Com", "Geo") for c in only_pairs[key]) and only_pairs["many"] == []
    only_singles = combinations(ObjectsConfig(), include_pairs=False)
    assert only_singles["Com"] == [] and all(len(c) == 1 for c in only_singles["train"])
    custom = combinations(ObjectsConfig(heldout_pairs=[("sphere", "cube")]))
    assert custom["Com"] == [("cube", "sphere")]  # canonical order = config order
    small = combinations(ObjectsConfig(train=["cube", "sphere"], ood=[]))
    assert small["train"] == [("cube",), ("sphere",), ("cube", "sphere")] and small["Com"] == []

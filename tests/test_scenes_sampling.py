"""Scene sampling: resting, non-overlapping placements that stay put in PyBullet."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pybullet as pb
import pytest
import torch

from components.errors import MultigraspError
from components.objects import (
    ObjectLibrary,
    ObjectsConfig,
    Scene,
    ScenesConfig,
    combinations,
    sample_scene,
    sample_settled_scenes,
    settle_scene,
)
from components.objects.sdf import mesh_signed_distance


@pytest.fixture(scope="module")
def library(tmp_path_factory) -> ObjectLibrary:
    # shared by the test files of one session (content-keyed, verified cache)
    return ObjectLibrary(ObjectsConfig(), tmp_path_factory.getbasetemp() / "objects-cache")


@pytest.fixture(scope="module")
def cfg() -> ScenesConfig:
    return ScenesConfig()


def scene_mix(library: ObjectLibrary, rng: np.random.Generator, n: int) -> list[tuple[str, ...]]:
    """Singles and pairs of all 11 objects and 3-5 small cylinders, drawn at random."""
    splits = combinations(library.cfg)
    pool = splits["train"] + splits["Com"] + splits["Geo"] + splits["many"]
    return [pool[i] for i in rng.choice(len(pool), size=n, replace=True)]


def closest_distance(lib: ObjectLibrary, a, b) -> float:
    """Independent check (not PyBullet): min over dense surface samples of A of the SDF of B, and vice versa.

    For meshes the SDF describes the visual mesh, which may differ from the collision
    decomposition PyBullet saw by < ~1.5 mm (the placement gap is 2 mm).
    """
    def one_way(x, y) -> float:
        pts = lib.get(x.name).sample_surface(512, seed=0)  # object frame of x
        world = pts @ x.matrix()[:3, :3].T + x.matrix()[:3, 3]
        inv = np.linalg.inv(y.matrix())
        local = world @ inv[:3, :3].T + inv[:3, 3]
        target = lib.get(y.name)
        if target.is_analytic:
            return float(target.sdf(torch.as_tensor(local)).min())
        return float(mesh_signed_distance(target.mesh, local).min())  # exact; avoids building SDF grids here

    return min(one_way(a, b), one_way(b, a))


def test_sampled_scenes_settle(library, cfg):
    """>= 95 % of 40 sampled scenes (singles, pairs, 3-5 cylinders) move < 2 mm in 1 s of simulation."""
    rng = np.random.default_rng(0)
    results = []
    for names in scene_mix(library, rng, 40):
        scene = sample_scene(library, names, rng, cfg)
        results.append(settle_scene(library, scene, cfg))
    stable = [r.stable for r in results]
    assert np.mean(stable) >= 0.95, [r.max_displacement_m for r in results if not r.stable]
    for r in results:
        assert r.stable == (r.max_displacement_m < cfg.settle_tolerance_m)
        assert len(r.displacements) == len(r.settled.objects) == len(r.rotations_rad)


def test_overlapping_placements_are_never_returned(library, cfg):
    rng = np.random.default_rng(1)
    client = pb.connect(pb.DIRECT)
    try:
        for names in scene_mix(library, rng, 60):
            scene = sample_scene(library, names, rng, cfg)
            bodies = [library.get(p.name).pybullet_body(client, p.position, p.quat_xyzw) for p in scene.objects]
            for (a, ba), (b, bb) in itertools.combinations(zip(scene.objects, bodies), 2):
                pb_gap = min((c[8] for c in pb.getClosestPoints(ba, bb, 1.0, physicsClientId=client)), default=np.inf)
                assert pb_gap >= cfg.min_gap_m - 1e-9
                assert closest_distance(library, a, b) >= 0.0, (a.name, b.name)
            for body in bodies:
                pb.removeBody(body, physicsClientId=client)
    finally:
        pb.disconnect(physicsClientId=client)


def test_max_gap_keeps_every_object_near_another(library):
    cfg = ScenesConfig(max_gap_m=0.02)
    rng = np.random.default_rng(3)
    client = pb.connect(pb.DIRECT)
    try:
        for names in [("capsule", "bar"), ("cube", "sphere"), ("small_cylinder",) * 4]:
            for _ in range(4):
                scene = sample_scene(library, names, rng, cfg)
                bodies = [library.get(p.name).pybullet_body(client, p.position, p.quat_xyzw) for p in scene.objects]
                for body in bodies:
                    gaps = [min((c[8] for c in pb.getClosestPoints(body, other, 1.0, physicsClientId=client)), default=np.inf)
                            for other in bodies if other != body]
                    assert cfg.min_gap_m - 1e-9 <= min(gaps) <= cfg.max_gap_m + 1e-9
                for body in bodies:
                    pb.removeBody(body, physicsClientId=client)
    finally:
        pb.disconnect(physicsClientId=client)


def test_impossible_max_gap_is_one_clear_error(library):
    cfg = ScenesConfig(max_gap_m=0.001, max_tries=5)  # below min_gap_m: no placement can satisfy both
    with pytest.raises(MultigraspError, match="max_gap_m"):
        sample_scene(library, ("cube", "sphere"), np.random.default_rng(0), cfg)


def test_placements_rest_on_the_table_within_the_xy_range(library, cfg):
    rng = np.random.default_rng(2)
    for names in [("cube", "duck"), ("torus",), ("small_cylinder",) * 5]:
        half = cfg.xy_half_range_many_m if len(names) > cfg.many_threshold else cfg.xy_half_range_m
        for _ in range(5):
            scene = sample_scene(library, names, rng, cfg)
            assert scene.names == names
            for p in scene.objects:
                assert abs(p.position[0]) <= half and abs(p.position[1]) <= half
                hull = library.get(p.name).collision_hull().vertices
                world = hull @ p.matrix()[:3, :3].T + p.matrix()[:3, 3]
                assert abs(world[:, 2].min()) < 1e-9  # lowest point on z = 0
                assert np.linalg.norm(p.quat_xyzw) == pytest.approx(1.0)


def test_sampling_is_deterministic_for_a_seed(library, cfg):
    a = sample_scene(library, ["bar", "sphere"], np.random.default_rng(7), cfg)
    b = sample_scene(library, ["bar", "sphere"], np.random.default_rng(7), cfg)
    c = sample_scene(library, ["bar", "sphere"], np.random.default_rng(8), cfg)
    assert a == b and a != c


def test_scene_round_trips_through_json(library, cfg):
    scene = sample_scene(library, ["frustum", "bunny"], np.random.default_rng(3), cfg)
    text = json.dumps(scene.to_dict())
    assert Scene.from_dict(json.loads(text)) == scene


def test_scene_round_trips_through_the_flat_table_columns(library, cfg):
    scene = sample_scene(library, ["frustum", "bunny"], np.random.default_rng(3), cfg)
    positions = [v for pl in scene.objects for v in pl.position]  # the synthesis tables' flattened columns
    quats = [v for pl in scene.objects for v in pl.quat_xyzw]
    assert Scene.from_arrays(list(scene.names), positions, quats) == scene


def test_impossible_scene_is_a_one_line_error_suggesting_a_larger_range(library):
    tight = ScenesConfig(xy_half_range_m=0.005, max_tries=30)
    with pytest.raises(MultigraspError) as excinfo:
        sample_scene(library, ["duck", "torus"], np.random.default_rng(4), tight)
    message = str(excinfo.value)
    assert "\n" not in message and "duck" in message and "torus" in message and "xy_half_range_m" in message


def test_unknown_name_in_a_scene_is_a_one_line_error(library, cfg):
    with pytest.raises(MultigraspError, match="unknown object 'mug'"):
        sample_scene(library, ["cube", "mug"], np.random.default_rng(0), cfg)


def test_sample_settled_scenes_returns_only_stable_scenes(library, cfg):
    got = sample_settled_scenes(library, ["capsule", "ellipsoid"], 4, np.random.default_rng(5), cfg)
    assert len(got) == 4
    for scene, result in got:
        assert result.stable and result.max_displacement_m < cfg.settle_tolerance_m
        assert result.settled.names == scene.names


def test_a_scene_that_falls_over_is_reported_unstable(library, cfg):
    """A cylinder balanced on its rim is not a resting pose: settling must catch it."""
    tilted = Scene.from_dict({"objects": [{"name": "cylinder", "position": [0.0, 0.0, 0.04], "quat_xyzw": [0.2588, 0.0, 0.0, 0.9659]}]})
    result = settle_scene(library, tilted, cfg)
    assert not result.stable and result.max_displacement_m > cfg.settle_tolerance_m


def test_max_gap_asks_for_one_cluster_not_only_a_neighbour_each(library):
    # four small cylinders (r 1.5 cm) in two touching pairs 10 cm apart: every cylinder has a neighbour within 1 cm,
    # but the two pairs do not fit in one hand together
    from components.objects.scenes import _within_max_gap

    client = pb.connect(pb.DIRECT)
    try:
        def bodies_at(xs):
            return [library.get("small_cylinder").pybullet_body(client, (x, 0.0, 0.025), (0.0, 0.0, 0.0, 1.0)) for x in xs]

        apart = bodies_at([0.0, 0.035, 0.135, 0.17])
        assert not _within_max_gap(client, apart, 0.01)
        row = bodies_at([0.5, 0.535, 0.57, 0.605])  # a row of four, 5 mm between neighbours
        assert _within_max_gap(client, row, 0.01)
        assert _within_max_gap(client, apart, None)
    finally:
        pb.disconnect(physicsClientId=client)


def test_max_gap_many_applies_above_the_many_threshold_only():
    from components.objects.scenes import max_gap_for

    cfg = ScenesConfig(max_gap_m=0.025, max_gap_many_m=0.01, many_threshold=3)
    assert max_gap_for(2, cfg) == 0.025 and max_gap_for(3, cfg) == 0.025
    assert max_gap_for(4, cfg) == 0.01 and max_gap_for(5, cfg) == 0.01
    assert max_gap_for(5, ScenesConfig(max_gap_m=0.025)) == 0.025  # unset: max_gap_m for every count


def test_cluster_placement_puts_five_small_cylinders_within_a_centimetre_of_each_other(library):
    # uniform placement in ±3.5 cm never finds five small cylinders in a 1 cm cluster (README); growing one does
    cfg = ScenesConfig(many_placement="cluster", max_gap_many_m=0.01, xy_half_range_many_m=0.035, max_tries=200)
    rng = np.random.default_rng(0)
    for _ in range(3):
        scene = sample_scene(library, ["small_cylinder"] * 5, rng, cfg)
        for a, b in itertools.combinations(scene.objects, 2):
            assert closest_distance(library, a, b) > 0.0015  # min_gap 2 mm, minus the SDF check's tolerance
        centroid = np.mean([pl.position[:2] for pl in scene.objects], axis=0)
        assert np.all(np.abs(centroid) <= 0.035 + 1e-9)
        # one cluster: linking objects closer than 1 cm (+ the check's tolerance) connects all five
        near = {(i, j) for (i, a), (j, b) in itertools.combinations(enumerate(scene.objects), 2)
                if closest_distance(library, a, b) <= 0.0115}
        reached, frontier = {0}, [0]
        while frontier:
            i = frontier.pop()
            for j in range(5):
                if j not in reached and ((i, j) in near or (j, i) in near):
                    reached.add(j)
                    frontier.append(j)
        assert reached == set(range(5))
    pair = sample_scene(library, ["cube", "cylinder"], np.random.default_rng(1), cfg)  # below the threshold: uniform
    assert all(abs(c) <= cfg.xy_half_range_m for pl in pair.objects for c in pl.position[:2])


def test_cluster_placement_without_a_gap_is_a_config_error():
    with pytest.raises(ValueError, match="max_gap_many_m"):
        ScenesConfig(many_placement="cluster")

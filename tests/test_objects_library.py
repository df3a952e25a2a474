"""Object library: the default objects, user meshes and their one-line errors, resting poses, PyBullet bodies."""

from __future__ import annotations

import logging

import numpy as np
import pybullet as pb
import pytest
import torch
import trimesh
import yaml
from scipy.spatial.transform import Rotation

from components.errors import MultigraspError
from components.objects import DEFAULT_OOD_OBJECTS, DEFAULT_TRAIN_OBJECTS, ObjectLibrary, ObjectsConfig, UserMesh
from components.objects.library import DEFAULT_LIBRARY_FILE
from components.objects.sdf import mesh_signed_distance


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory):
    # shared by the test files of one session (content-keyed, verified cache)
    return tmp_path_factory.getbasetemp() / "objects-cache"


@pytest.fixture(scope="module")
def library(cache_dir) -> ObjectLibrary:
    return ObjectLibrary(ObjectsConfig(), cache_dir)


def user_library(cache_dir, tmp_path, shape: trimesh.Trimesh | None, suffix=".obj", **user_fields) -> ObjectLibrary:
    """A library with one user mesh: ``shape`` written to ``tmp_path``, or the file given as ``mesh=``."""
    if "mesh" not in user_fields:
        path = tmp_path / f"user{suffix}"
        shape.export(str(path))
        user_fields["mesh"] = path
    user = UserMesh(name=user_fields.pop("name", "thing"), mass_kg=user_fields.pop("mass_kg", 0.05), **user_fields)
    return ObjectLibrary(ObjectsConfig(user=[user]), cache_dir)


def one_line_error(excinfo) -> str:
    message = str(excinfo.value)
    assert "\n" not in message and message
    return message


# ----------------------------------------------------------------------------- the default library


def test_default_library_has_8_training_and_3_ood_objects_of_3_to_8_cm(library):
    assert library.train == DEFAULT_TRAIN_OBJECTS and len(library.train) == 8
    assert library.ood == DEFAULT_OOD_OBJECTS and len(library.ood) == 3
    for name in library.train + library.ood + ["small_cylinder"]:
        obj = library.get(name)
        assert obj.mesh.is_watertight, name
        assert 0.03 - 1e-9 <= obj.mesh.extents.max() <= 0.08, (name, obj.mesh.extents)
        assert obj.graspable_width() <= library.cfg.max_graspable_width_m
        assert np.allclose(obj.mesh.center_mass, 0.0, atol=1e-6), name  # object frame: origin at the centre of mass
        assert obj.radius == pytest.approx(np.linalg.norm(obj.mesh.vertices, axis=1).max())
        assert 0.005 < obj.mass_kg < 0.2 and obj.friction > 0


def test_training_objects_fit_two_at_a_time_in_the_hand(library):
    """Paper: objects rescaled so that several fit in one hand — every pair together is narrower than ~1.5 hands."""
    widths = sorted(library.get(n).graspable_width() for n in library.train)
    assert widths[-1] + widths[-2] < 1.5 * library.cfg.max_graspable_width_m


def test_config_defaults_match_the_roles_in_library_yaml():
    data = yaml.safe_load(DEFAULT_LIBRARY_FILE.read_text())
    roles = {name: entry["role"] for name, entry in data["objects"].items()}
    assert [n for n, r in roles.items() if r == "train"] == DEFAULT_TRAIN_OBJECTS
    assert [n for n, r in roles.items() if r == "ood"] == DEFAULT_OOD_OBJECTS
    assert roles[ObjectsConfig().many_object] == "many"


def test_ood_meshes_are_read_from_the_installed_pybullet_data(library):
    import pybullet_data

    duck = library.get("duck")
    assert duck.spec.shape.source == "pybullet_data:duck.obj"
    source = trimesh.load(pybullet_data.getDataPath() + "/duck.obj", force="mesh")
    # same shape up to the scale and the object frame (a rigid motion): compare the sorted principal moments
    src = source.copy()
    src.merge_vertices(merge_tex=True, merge_norm=True)
    src.apply_scale(0.036)
    np.testing.assert_allclose(np.sort(np.linalg.eigvalsh(src.moment_inertia)), np.sort(np.diag(duck.mesh.moment_inertia)), rtol=1e-6)


def test_fingerprint_is_deterministic_and_tracks_the_definition(library, cache_dir, tmp_path):
    assert library.fingerprint("duck") == ObjectLibrary(ObjectsConfig(), cache_dir).fingerprint("duck")
    assert len({library.fingerprint(n) for n in library.names}) == len(library.names)
    box = trimesh.creation.box(extents=(0.04, 0.03, 0.02))
    a = user_library(cache_dir, tmp_path, box, scale=1.0)
    b = user_library(cache_dir, tmp_path, box, scale=0.9)
    assert a.fingerprint("thing") != b.fingerprint("thing")


def test_sample_surface_is_even_on_the_surface_and_seeded(library):
    for name in ("cube", "ellipsoid", "torus", "duck"):
        obj = library.get(name)
        pts = obj.sample_surface(1024, seed=3)
        assert pts.shape == (1024, 3)
        np.testing.assert_array_equal(pts, obj.sample_surface(1024, seed=3))
        assert not np.array_equal(pts, obj.sample_surface(1024, seed=4))
        if obj.is_analytic:
            assert np.abs(obj.sdf(torch.as_tensor(pts)).numpy()).max() < 1e-9, name  # projected onto the exact surface
        else:
            assert np.abs(mesh_signed_distance(obj.mesh, pts)).max() < 1e-9, name  # on the mesh
        # even: nearest-neighbour spacing varies much less than for uniform random samples
        nn = trimesh.points.PointCloud(pts).kdtree.query(pts, k=2)[0][:, 1]
        rnd = trimesh.sample.sample_surface(obj.mesh, 1024, seed=3)[0]
        nn_rnd = trimesh.points.PointCloud(rnd).kdtree.query(rnd, k=2)[0][:, 1]
        assert nn.std() / nn.mean() < 0.6 * nn_rnd.std() / nn_rnd.mean(), name


# ----------------------------------------------------------------------------- resting poses


@pytest.mark.parametrize("name", [*DEFAULT_TRAIN_OBJECTS, *DEFAULT_OOD_OBJECTS, "small_cylinder"])
def test_stable_poses_rest_on_the_table_and_survive_a_pybullet_drop(library, name):
    """Each checked pose, at a random yaw, dropped from ``stable_pose_drop_m``: it stays in that pose.

    (Lying cones and cylinders are only neutrally stable: a harder drop can set them rolling.)
    """
    obj = library.get(name)
    poses = obj.stable_poses()
    assert poses and abs(sum(p for _, p in poses) - 1.0) < 1e-9
    hull = obj.collision_hull().vertices
    rng = np.random.default_rng(0)
    client = pb.connect(pb.DIRECT)
    try:
        pb.setGravity(0, 0, -9.81, physicsClientId=client)
        pb.setTimeStep(1 / 240, physicsClientId=client)
        table = pb.createMultiBody(0, pb.createCollisionShape(pb.GEOM_PLANE, physicsClientId=client), physicsClientId=client)
        pb.changeDynamics(table, -1, lateralFriction=0.8, physicsClientId=client)
        checked = poses[:: max(len(poses) // 6, 1)]  # up to ~6 poses spread over the list
        bodies = []
        for i, (transform, _) in enumerate(checked):
            world = hull @ transform[:3, :3].T + transform[:3, 3]
            assert abs(world[:, 2].min()) < 1e-9  # lowest point of the collision geometry on z = 0
            visual = obj.mesh.vertices @ transform[:3, :3].T + transform[:3, 3]
            assert abs(visual[:, 2].min()) < 1.5e-3  # the visual mesh too (decompositions differ by < 1.5 mm)
            yaw = Rotation.from_euler("z", rng.uniform(0, 2 * np.pi))
            rotation = yaw * Rotation.from_matrix(transform[:3, :3])
            start = [0.2 * i, 0.0, transform[2, 3] + library.cfg.stable_pose_drop_m]
            bodies.append((obj.pybullet_body(client, start, rotation.as_quat()), start, rotation, transform[2, 3]))
        for _ in range(360):
            pb.stepSimulation(physicsClientId=client)
        for body, start, rotation, rest_z in bodies:
            pos, quat = pb.getBasePositionAndOrientation(body, physicsClientId=client)
            assert abs(pos[2] - rest_z) < 1e-3, name
            assert np.hypot(pos[0] - start[0], pos[1] - start[1]) < 2e-3, name
            assert np.degrees((Rotation.from_quat(quat) * rotation.inv()).magnitude()) < 5.0, name
    finally:
        pb.disconnect(physicsClientId=client)


# ----------------------------------------------------------------------------- PyBullet bodies


def test_pybullet_bodies_use_native_shapes_hulls_and_decompositions(library):
    client = pb.connect(pb.DIRECT)
    try:
        kinds = {}
        for name in ("sphere", "cube", "cylinder", "capsule", "ellipsoid", "duck", "torus", "bunny"):
            obj = library.get(name)
            body = obj.pybullet_body(client, (0, 0, 1), (0, 0, 0, 1))
            shapes = pb.getCollisionShapeData(body, -1, physicsClientId=client)
            kinds[name] = (shapes[0][2], len(shapes))
            assert pb.getDynamicsInfo(body, -1, physicsClientId=client)[0] == pytest.approx(obj.mass_kg)
            assert pb.getDynamicsInfo(body, -1, physicsClientId=client)[1] == pytest.approx(obj.friction)
        assert kinds["sphere"][0] == pb.GEOM_SPHERE and kinds["cube"][0] == pb.GEOM_BOX
        assert kinds["cylinder"][0] == pb.GEOM_CYLINDER and kinds["capsule"][0] == pb.GEOM_CAPSULE
        assert kinds["ellipsoid"] == (pb.GEOM_MESH, 1)
        assert kinds["duck"][1] == 5  # pybullet_data's duck_vhacd.obj pieces
        assert kinds["torus"][1] >= 8 and kinds["bunny"][1] >= 2
    finally:
        pb.disconnect(physicsClientId=client)


def test_torus_collision_keeps_its_hole(library):
    torus = library.get("torus")
    client = pb.connect(pb.DIRECT)
    try:
        body = torus.pybullet_body(client, (0, 0, 0), (0, 0, 0, 1))
        ball = pb.createMultiBody(0.01, pb.createCollisionShape(pb.GEOM_SPHERE, radius=0.01, physicsClientId=client), basePosition=(0, 0, 0), physicsClientId=client)
        gap = min(p[8] for p in pb.getClosestPoints(body, ball, 1.0, physicsClientId=client))
        hole = torus.spec.shape.major_radius_m - torus.spec.shape.minor_radius_m - 0.01
        assert gap == pytest.approx(hole, abs=1e-3)
    finally:
        pb.disconnect(physicsClientId=client)


# ----------------------------------------------------------------------------- user meshes and errors


def test_unknown_object_name_is_a_one_line_error_listing_the_known_ones(cache_dir):
    with pytest.raises(MultigraspError) as excinfo:
        ObjectLibrary(ObjectsConfig(train=["cube", "banana"]), cache_dir)
    message = one_line_error(excinfo)
    assert "banana" in message and "objects.train" in message and "cube" in message and "duck" in message
    with pytest.raises(MultigraspError, match="unknown object 'kiwi'"):
        ObjectLibrary(ObjectsConfig(), cache_dir).get("kiwi")


def test_missing_mesh_file_is_a_one_line_error_with_the_path(cache_dir, tmp_path):
    missing = tmp_path / "nowhere" / "mug.obj"
    with pytest.raises(MultigraspError) as excinfo:
        user_library(cache_dir, tmp_path, None, mesh=missing)
    message = one_line_error(excinfo)
    assert str(missing) in message and "does not exist" in message


def test_mesh_larger_than_the_hand_can_hold_is_rejected_with_a_scale_suggestion(cache_dir, tmp_path):
    big = trimesh.creation.box(extents=(300.0, 200.0, 20.0))  # a tray in millimetres, read as metres
    with pytest.raises(MultigraspError) as excinfo:
        user_library(cache_dir, tmp_path, big, suffix=".stl", scale=0.001)
    message = one_line_error(excinfo)
    assert "too large" in message and "20.0 cm" in message and "scale:" in message
    suggested = float(message.split("scale: ")[1].split("`")[0])
    fits = user_library(cache_dir, tmp_path, big, suffix=".stl", scale=suggested * 0.25)  # a 7.5 x 5 cm tray
    assert fits.get("thing").graspable_width() < fits.cfg.max_graspable_width_m


@pytest.mark.parametrize("content, suffix, expected", [
    (b"just some notes, not a mesh\n", ".txt", "not a mesh file"),
    (b"this is not wavefront\n\x00\x01garbage", ".obj", "no triangles"),
    (b"solid x\n facet normal 0 0 1\n outer loop\n vertex 0 0", ".stl", "no triangles"),
    (b"ply\nformat binary_little_endian 1.0\nelement vertex 10\nproperty float x\nend_header\n\x01\x02", ".ply", "could not read"),
])
def test_non_mesh_file_given_as_mesh_is_a_one_line_error(cache_dir, tmp_path, content, suffix, expected):
    path = tmp_path / f"bad{suffix}"
    path.write_bytes(content)
    with pytest.raises(MultigraspError) as excinfo:
        user_library(cache_dir, tmp_path, None, mesh=path)
    message = one_line_error(excinfo)
    assert expected in message and str(path) in message


def test_open_mesh_is_rejected_unless_convex_hull_repair_is_asked(cache_dir, tmp_path, caplog):
    sphere = trimesh.creation.icosphere(3, 0.025)
    dome = trimesh.Trimesh(sphere.vertices, sphere.faces[sphere.triangles_center[:, 2] > 0])  # open at the bottom: a big hole
    assert not dome.is_watertight
    with pytest.raises(MultigraspError) as excinfo:
        user_library(cache_dir, tmp_path, dome)
    message = one_line_error(excinfo)
    assert "not watertight" in message and "repair: convex_hull" in message
    with caplog.at_level(logging.WARNING):
        lib = user_library(cache_dir, tmp_path, dome, repair="convex_hull")
    assert "convex hull" in caplog.text
    closed = lib.get("thing")
    assert closed.mesh.is_watertight and closed.mesh.volume == pytest.approx(dome.convex_hull.volume, rel=1e-6)


def test_small_hole_is_filled_with_a_warning(cache_dir, tmp_path, caplog):
    box = trimesh.creation.box(extents=(0.04, 0.03, 0.02))
    box.update_faces(np.arange(1, len(box.faces)))  # one missing triangle
    assert not box.is_watertight
    with caplog.at_level(logging.WARNING):
        lib = user_library(cache_dir, tmp_path, box)
    assert "filled its holes" in caplog.text
    assert lib.get("thing").mesh.is_watertight


def test_user_mesh_in_millimetres_with_scale_works_end_to_end(cache_dir, tmp_path):
    mug_like = trimesh.creation.annulus(r_min=20.0, r_max=30.0, height=70.0)  # a cup wall in mm: non-convex
    lib = user_library(cache_dir, tmp_path, mug_like, suffix=".ply", scale=0.001, name="cup", mass_kg=None)
    cup = lib.get("cup")
    assert cup.mesh.extents.max() == pytest.approx(0.07, rel=1e-6)
    assert cup.mass_kg == pytest.approx(lib.cfg.default_density_kg_m3 * cup.mesh.volume)
    centre = np.zeros((1, 3))  # in the hole, on the SDF's medial axis (a kink: trilinear error < 1 voxel)
    exact = mesh_signed_distance(cup.mesh, centre)[0]
    assert exact > 0.019 and cup.sdf(torch.as_tensor(centre)).item() == pytest.approx(exact, abs=2e-3)
    assert len(cup.convex_parts()) >= 2  # pybullet.vhacd decomposition, cached
    assert "cup" in lib.names


def test_a_dense_user_mesh_is_simplified_once_and_stays_on_its_surface(cache_dir, tmp_path, caplog):
    """A scan-like mesh (an icosphere of 20,480 triangles here; one of 327,680 was still in trimesh's resting poses
    after 12 min) is decimated to max_faces on load, logged once, and read from the cache after; 0 keeps it."""
    ball = trimesh.creation.icosphere(subdivisions=5, radius=0.03)
    assert len(ball.faces) == 20480
    with caplog.at_level(logging.WARNING):
        lib = user_library(cache_dir, tmp_path, ball, name="scan", max_faces=2000)
    assert caplog.text.count("has 20480 triangles; simplified to") == 1
    mesh = lib.get("scan").mesh
    assert len(mesh.faces) <= 2000 and mesh.is_watertight
    radii = np.linalg.norm(mesh.vertices - mesh.center_mass, axis=1)
    assert np.abs(radii - 0.03).max() < 1e-3  # the surface kept to within 1 mm
    assert mesh.volume == pytest.approx(ball.volume, rel=0.02)
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        again = user_library(cache_dir, tmp_path, ball, name="scan", max_faces=2000)
    assert "simplified" not in caplog.text and np.array_equal(again.get("scan").mesh.faces, mesh.faces)
    finer = user_library(cache_dir, tmp_path, ball, name="scan", max_faces=3000)
    assert 2000 < len(finer.get("scan").mesh.faces) <= 3000 and finer.fingerprint("scan") != lib.fingerprint("scan")
    from components.objects.meshes import simplify_mesh

    assert simplify_mesh(ball, "scan", "f.obj", 0) is ball and simplify_mesh(ball, "scan", "f.obj", 20480) is ball


def test_library_meshes_are_never_simplified_and_keep_their_fingerprints(library):
    from components.objects.shapes import MeshShape

    duck = library.get("duck")
    assert isinstance(duck.spec.shape, MeshShape) and duck.spec.shape.max_faces is None


def test_user_mesh_may_not_shadow_a_library_object(cache_dir, tmp_path):
    with pytest.raises(MultigraspError, match="name of a library object"):
        user_library(cache_dir, tmp_path, trimesh.creation.box(extents=(0.04, 0.03, 0.02)), name="duck")


def test_config_rejects_bad_values_at_load_time():
    from pydantic import ValidationError

    with pytest.raises(ValidationError):
        ObjectsConfig(sdf_grid_resolution=2)
    with pytest.raises(ValidationError):
        ObjectsConfig(train=["cube"], ood=["cube"])
    with pytest.raises(ValidationError):
        ObjectsConfig(heldout_pairs=[("cube", "duck")])
    with pytest.raises(ValidationError):
        UserMesh(name="x", mesh="x.obj", scale=0)
    with pytest.raises(ValidationError):
        ObjectsConfig(typo_field=1)

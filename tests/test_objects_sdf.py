"""SDFs: analytic primitives against exact mesh distances, cached mesh grids against trimesh."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import trimesh

from components.objects import ObjectLibrary, ObjectsConfig
from components.objects import sdf as S
from components.objects.shapes import FrustumShape, capsule_mesh

MM = 1e-3


def reference_signed_distance(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """trimesh's signed distance, negative inside (trimesh: positive inside).

    Computed in millimetres: trimesh.triangles.closest_point compares squared lengths with an
    absolute 1e-12, which misclassifies sub-millimetre triangles when working in metres.
    """
    scaled = mesh.copy()
    scaled.apply_scale(1000.0)
    return -trimesh.proximity.signed_distance(scaled, points * 1000.0) / 1000.0


def random_points(bounds: np.ndarray, n: int, margin: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(bounds[0] - margin, bounds[1] + margin, size=(n, 3))


def near_surface_points(mesh: trimesh.Trimesh, n: int, band: float, seed: int) -> np.ndarray:
    """Points within ``band`` of the surface: surface samples moved along the face normal by U(-band, band)."""
    rng = np.random.default_rng(seed)
    pts, faces = trimesh.sample.sample_surface(mesh, n, seed=seed)
    return pts + mesh.face_normals[faces] * rng.uniform(-band, band, size=(n, 1))


@pytest.fixture(scope="module")
def library(tmp_path_factory) -> ObjectLibrary:
    # shared by the test files of one session (content-keyed, verified cache)
    return ObjectLibrary(ObjectsConfig(), tmp_path_factory.getbasetemp() / "objects-cache")


# ----------------------------------------------------------------------------- analytic


def test_sphere_sdf_is_exact():
    rng = np.random.default_rng(0)
    p = torch.as_tensor(rng.normal(size=(2000, 3)) * 0.05)
    d = S.sphere_sdf(p, 0.025)
    expected = np.linalg.norm(p.numpy(), axis=1) - 0.025
    np.testing.assert_allclose(d.numpy(), expected, atol=1e-12)
    assert S.sphere_sdf(torch.zeros(1, 3, dtype=torch.float64), 0.025).item() == pytest.approx(-0.025)


@pytest.mark.parametrize(
    "name, fn, mesh, tol",
    [
        ("box", lambda p: S.box_sdf(p, (0.02, 0.0125, 0.01)), trimesh.creation.box(extents=(0.04, 0.025, 0.02)), 1e-9),
        ("cylinder", lambda p: S.cylinder_sdf(p, 0.02, 0.03), trimesh.creation.cylinder(radius=0.02, height=0.06, sections=512), 5e-6),
        ("capsule", lambda p: S.capsule_sdf(p, 0.015, 0.02), capsule_mesh(0.015, 0.04, 256), 5e-6),
        (
            "hex_prism",
            lambda p: S.hexagonal_prism_sdf(p, 0.02, 0.025),
            trimesh.creation.cylinder(radius=0.04 / math.sqrt(3), height=0.05, sections=6),
            1e-9,
        ),
        ("torus", lambda p: S.torus_sdf(p, 0.022, 0.009), trimesh.creation.torus(0.022, 0.009, major_sections=256, minor_sections=128), 5e-6),
        ("ellipsoid", lambda p: S.ellipsoid_sdf(p, (0.03, 0.02, 0.015)), trimesh.creation.icosphere(6, 1.0).apply_scale((0.03, 0.02, 0.015)), 5e-6),
    ],
)
def test_primitive_sdf_matches_exact_mesh_distance(name, fn, mesh, tol):
    """Box / hex prism are polyhedra (exact); curved shapes vs fine tessellations (chord error < tol)."""
    points = np.concatenate([random_points(mesh.bounds, 250, 0.02, 1), near_surface_points(mesh, 250, 0.01, 2)])
    expected = reference_signed_distance(mesh, points)
    got = fn(torch.as_tensor(points)).numpy()
    assert np.abs(got - expected).max() < tol, name
    assert np.all(np.sign(got[np.abs(expected) > tol]) == np.sign(expected[np.abs(expected) > tol]))


def test_frustum_sdf_matches_mesh_in_object_frame():
    shape = FrustumShape(type="frustum", radius_bottom_m=0.025, radius_top_m=0.015, height_m=0.05)
    mesh = shape.build_mesh(ObjectsConfig(primitive_sections=512))
    assert np.allclose(mesh.center_mass, 0.0, atol=2e-6)  # the object frame is centred at the centroid
    points = np.concatenate([random_points(mesh.bounds, 600, 0.02, 3), near_surface_points(mesh, 600, 0.01, 4)])
    expected = reference_signed_distance(mesh, points)
    got = shape.sdf(torch.as_tensor(points)).numpy()
    assert np.abs(got - expected).max() < 5e-6


def test_sdf_normals_of_a_sphere_point_radially(library):
    sphere = library.get("sphere")
    rng = np.random.default_rng(5)
    p = torch.as_tensor(rng.normal(size=(500, 3)) * 0.04, dtype=torch.float32)
    d, n = sphere.sdf_and_normal(p)
    radial = p / p.norm(dim=-1, keepdim=True)
    assert torch.allclose(n, radial, atol=1e-5)
    assert torch.allclose(n.norm(dim=-1), torch.ones(500), atol=1e-5)
    assert not d.requires_grad and not n.requires_grad


def test_sdf_and_normal_stays_differentiable_when_points_require_grad(library):
    """E_fc uses normals of contact points: the normal must carry gradients to the points."""
    for name in ("cube", "ellipsoid", "bunny"):
        obj = library.get(name)
        p = (torch.randn(64, 3, dtype=torch.float64) * 0.01 + torch.tensor([0.0, 0.0, 0.03], dtype=torch.float64)).requires_grad_(True)
        d, n = obj.sdf_and_normal(p)
        (g,) = torch.autograd.grad((d + n[:, 0]).sum(), p)
        assert torch.isfinite(g).all(), name


@pytest.mark.parametrize("name", ["sphere", "cube", "cylinder", "capsule", "ellipsoid", "frustum", "bar", "hex_prism", "torus"])
def test_analytic_sdf_gradients_are_finite_unit_and_match_finite_differences(library, name):
    obj = library.get(name)
    rng = np.random.default_rng(6)
    p = torch.as_tensor(rng.normal(size=(300, 3)) * 0.03, dtype=torch.float64)
    p = torch.cat([p, torch.zeros(1, 3, dtype=torch.float64)])  # the centre: a singular point of several formulas
    d, n = obj.sdf_and_normal(p)
    assert torch.isfinite(d).all() and torch.isfinite(n).all()
    grad_norm = n.norm(dim=-1)
    assert ((grad_norm - 1).abs() < 1e-6).float().mean() > 0.99
    eps = 1e-7
    fd = torch.stack([(obj.sdf(p + eps * e) - obj.sdf(p - eps * e)) / (2 * eps) for e in torch.eye(3, dtype=torch.float64)], dim=-1)
    agree = (fd - n).norm(dim=-1) < 1e-4
    assert agree.float().mean() > 0.97  # off the measure-zero creases (edges, medial axis)


def test_sdf_runs_in_the_dtype_and_device_of_the_points(library):
    for name in ("cube", "bunny"):
        obj = library.get(name)
        for dtype in (torch.float32, torch.float64):
            d = obj.sdf(torch.zeros(4, 2, 3, dtype=dtype))
            assert d.shape == (4, 2) and d.dtype == dtype and d.device.type == "cpu"


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_sdf_on_cuda_matches_cpu(library):
    p = torch.randn(1000, 3) * 0.03
    for name in ("cube", "frustum", "ellipsoid", "bunny"):
        obj = library.get(name)
        d_cpu, n_cpu = obj.sdf_and_normal(p)
        d_gpu, n_gpu = obj.sdf_and_normal(p.cuda())
        assert d_gpu.device.type == "cuda"
        assert torch.allclose(d_gpu.cpu(), d_cpu, atol=1e-5)


# ----------------------------------------------------------------------------- mesh grids


def test_exact_mesh_distance_agrees_with_brute_force():
    mesh = trimesh.creation.icosphere(4, 0.03)
    mesh.apply_scale((1.0, 0.7, 0.5))
    points = np.concatenate([random_points(mesh.bounds, 300, 0.02, 7), near_surface_points(mesh, 300, 0.005, 8)])
    got = S.mesh_signed_distance(mesh, points)
    brute = []
    for p in points:
        bary = S.closest_point_barycentric(mesh.triangles, np.repeat(p[None], len(mesh.faces), axis=0))
        closest = np.einsum("ij,ijk->ik", bary, mesh.triangles)
        brute.append(np.linalg.norm(closest - p, axis=1).min())
    np.testing.assert_allclose(np.abs(got), np.array(brute), atol=1e-12)
    np.testing.assert_array_equal(np.sign(got), np.sign(reference_signed_distance(mesh, points)))


@pytest.mark.parametrize("name", ["bunny", pytest.param("duck", marks=pytest.mark.slow)])
def test_mesh_grid_sdf_matches_trimesh_within_1mm(library, name):
    """1,000 points within 1 cm of the surface (inside and outside): max |grid - trimesh| < 1 mm."""
    obj = library.get(name)
    points = near_surface_points(obj.mesh, 1000, 0.01, seed=9)
    expected = reference_signed_distance(obj.mesh, points)
    got = obj.sdf(torch.as_tensor(points, dtype=torch.float32)).numpy()
    err = np.abs(got - expected)
    assert err.max() < 1.0 * MM, f"{name}: max error {err.max() * 1000:.3f} mm"


def test_mesh_grid_normals_follow_the_surface(library):
    bunny = library.get("bunny")
    pts, faces = trimesh.sample.sample_surface(bunny.mesh, 500, seed=10)
    outside = pts + bunny.mesh.face_normals[faces] * 0.003
    _, n = bunny.sdf_and_normal(torch.as_tensor(outside, dtype=torch.float32))
    cos = (n.numpy() * bunny.mesh.face_normals[faces]).sum(axis=1)
    assert np.median(cos) > 0.95


def test_grid_sdf_outside_the_grid_is_the_distance_to_the_box_plus_the_edge_value(library):
    bunny = library.get("bunny")
    grid = bunny.sdf_grid()
    far = torch.tensor([[1.0, 0.0, 0.0], [0.0, -2.0, 0.5]], dtype=torch.float64)
    d = bunny.sdf(far).numpy()
    exact = reference_signed_distance(bunny.mesh, far.numpy())
    assert np.all(d >= exact - 1e-6)  # an upper bound...
    assert np.all(d < exact + np.linalg.norm(grid.upper - grid.lower))  # ...never far off
    on_axis = torch.tensor([[float(grid.upper[0]) + 0.1, 0.0, 0.0]], dtype=torch.float64)
    inside_edge = torch.tensor([[float(grid.upper[0]), 0.0, 0.0]], dtype=torch.float64)
    assert bunny.sdf(on_axis).item() == pytest.approx(bunny.sdf(inside_edge).item() + 0.1, abs=1e-9)


def test_trilinear_interpolation_is_exact_for_linear_fields_and_differentiable():
    axes = [torch.linspace(-1, 1, 9, dtype=torch.float64)] * 3
    x, y, z = torch.meshgrid(*axes, indexing="ij")
    values = 0.3 * x - 0.2 * y + 0.5 * z + 0.1
    lower, upper = torch.full((3,), -1.0, dtype=torch.float64), torch.full((3,), 1.0, dtype=torch.float64)
    p = (torch.rand(50, 3, dtype=torch.float64) * 2 - 1).requires_grad_(True)
    f = S.grid_sdf(values, lower, upper, p)
    torch.testing.assert_close(f, 0.3 * p[:, 0] - 0.2 * p[:, 1] + 0.5 * p[:, 2] + 0.1)
    (g,) = torch.autograd.grad(f.sum(), p)
    torch.testing.assert_close(g, torch.tensor([0.3, -0.2, 0.5], dtype=torch.float64).expand(50, 3))
    assert torch.autograd.gradcheck(lambda q: S.grid_sdf(values ** 2, lower, upper, q), (p[:5].detach().requires_grad_(True),))


def test_corrupt_sdf_cache_is_rebuilt_not_trusted(tmp_path_factory, caplog):
    cfg = ObjectsConfig(sdf_grid_resolution=24)  # small grid: quick to rebuild
    cache_dir = tmp_path_factory.getbasetemp() / "objects-cache"
    first = ObjectLibrary(cfg, cache_dir).get("bunny")
    probe = torch.tensor([[0.0, 0.0, 0.0], [0.01, 0.02, 0.0]], dtype=torch.float64)
    expected = first.sdf(probe)
    grid_file = first.sdf_grid_path()
    assert grid_file.exists()

    grid_file.write_bytes(b"not a zip file at all")  # unreadable
    again = ObjectLibrary(cfg, cache_dir).get("bunny")
    torch.testing.assert_close(again.sdf(probe), expected)
    assert "unreadable" in caplog.text

    # a valid npz whose content no longer matches its hash (one flipped value)
    with np.load(grid_file) as data:
        arrays = {k: data[k] for k in data.files}
    arrays["values"] = arrays["values"].copy()
    arrays["values"][3, 3, 3] += 1.0
    with open(grid_file, "wb") as fh:
        np.savez(fh, **arrays)
    caplog.clear()
    third = ObjectLibrary(cfg, cache_dir).get("bunny")
    torch.testing.assert_close(third.sdf(probe), expected)
    assert "corrupt" in caplog.text
    assert S.load_sdf_grid(grid_file, key="another key") is None

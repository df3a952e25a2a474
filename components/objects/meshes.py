"""Mesh files: loading, validation/repair, the object frame, convex decompositions, resting poses.

Every problem with a user's file is a one-line :class:`MultigraspError` naming the object,
the file and the fix.
"""

from __future__ import annotations

import logging
import subprocess
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import ConvexHull

from components.errors import MultigraspError

log = logging.getLogger(__name__)

MESH_SUFFIXES = (".obj", ".stl", ".ply")
#: Products of inertia below this fraction of the trace are treated as zero (frame kept as in the file).
INERTIA_OFFDIAG_TOL = 1e-6
#: Seconds allowed to one pybullet.vhacd run (in a child process) before it is reported as failed.
VHACD_TIMEOUT_S = 600


# ----------------------------------------------------------------------------- loading


def load_mesh_file(path: Path, name: str) -> trimesh.Trimesh:
    """Read an OBJ / STL / PLY file as one triangle mesh (all parts concatenated), file units."""
    if not path.exists():
        raise MultigraspError(f"object '{name}': mesh file {path} does not exist; fix the path (relative paths are resolved from {Path.cwd()})")
    if path.is_dir() or path.suffix.lower() not in MESH_SUFFIXES:
        raise MultigraspError(f"object '{name}': {path} is not a mesh file (expected {', '.join(MESH_SUFFIXES)}); point `mesh:` at an OBJ, STL or PLY file")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            mesh = trimesh.load(str(path), force="mesh", process=False)
    except Exception as exc:  # noqa: BLE001 - trimesh raises many types on bad files
        raise MultigraspError(f"object '{name}': could not read {path} as a mesh ({type(exc).__name__}: {exc}); re-export it as OBJ, STL or PLY") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0 or len(mesh.vertices) < 4:
        raise MultigraspError(f"object '{name}': {path} contains no triangles; re-export it as a triangle mesh (OBJ, STL or PLY)")
    if not np.isfinite(mesh.vertices).all():
        raise MultigraspError(f"object '{name}': {path} has NaN or infinite vertex coordinates; re-export the mesh")
    return mesh


def clean_mesh(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Merge duplicated vertices (incl. UV / normal seams, which make OBJ files look open), drop degenerate and duplicate faces."""
    mesh = mesh.copy()
    mesh.merge_vertices(merge_tex=True, merge_norm=True)
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.update_faces(mesh.unique_faces())
    mesh.remove_unreferenced_vertices()
    return mesh


def simplify_mesh(mesh: trimesh.Trimesh, name: str, path: Path | str, max_faces: int | None) -> trimesh.Trimesh:
    """``mesh`` with at most ``max_faces`` triangles (quadric decimation, trimesh's wrapper of fast-simplification;
    UserMesh.max_faces), logged; unchanged if it has no more, or ``max_faces`` is None or 0.  Decimation keeps the
    surface within a fraction of the removed edges' length; a hole it opens is left to :func:`make_watertight`."""
    if not max_faces or len(mesh.faces) <= max_faces:
        return mesh
    simple = mesh.simplify_quadric_decimation(face_count=max_faces)
    if len(simple.faces) == 0:
        raise MultigraspError(f"object '{name}': simplifying {path} to {max_faces} triangles left none; raise "
                              "its max_faces (objects.user) or simplify the file yourself")
    log.warning("object '%s': %s has %d triangles; simplified to %d (objects.user max_faces; 0 keeps every one)",
                name, path, len(mesh.faces), len(simple.faces))
    return simple


def make_watertight(mesh: trimesh.Trimesh, name: str, path: Path | str, repair: str) -> trimesh.Trimesh:
    """A closed, outward-oriented version of ``mesh``, or a one-line error.

    ``repair='fill_holes'``: fill small holes (trimesh.repair.fill_holes, warns); still open -> error.
    ``repair='convex_hull'``: replace an open mesh by its convex hull (warns).
    """
    if not mesh.is_watertight:
        if repair == "convex_hull":
            log.warning("object '%s': %s is not watertight; using its convex hull as requested (repair: convex_hull)", name, path)
            mesh = mesh.convex_hull
        else:
            open_edges = _count_open_edges(mesh)
            trimesh.repair.fill_holes(mesh)
            if not mesh.is_watertight:
                raise MultigraspError(
                    f"object '{name}': mesh {path} is not watertight ({open_edges} open edges), so its inside is undefined; "
                    "close it (e.g. MeshLab 'Close Holes', Blender 3D-Print toolbox) or set `repair: convex_hull` to use its convex hull"
                )
            log.warning("object '%s': %s had %d open edges; filled its holes to make it watertight", name, path, open_edges)
    trimesh.repair.fix_normals(mesh)
    if mesh.volume <= 0:
        raise MultigraspError(f"object '{name}': mesh {path} encloses no volume; check that it is a closed solid")
    return mesh


def _count_open_edges(mesh: trimesh.Trimesh) -> int:
    """Edges used by exactly one face."""
    return int((np.bincount(mesh.edges_unique_inverse, minlength=len(mesh.edges_unique)) == 1).sum())


# ----------------------------------------------------------------------------- object frame


def object_frame_transform(mesh: trimesh.Trimesh) -> np.ndarray:
    """4x4 transform from mesh coordinates to the object frame: origin at the centre of mass
    (uniform density), axes along the principal axes of inertia when the mesh's own axes are
    not already principal (so PyBullet's diagonal inertia is exact and its base frame equals
    the object frame).
    """
    com = np.asarray(mesh.center_mass)
    inertia = np.asarray(mesh.moment_inertia)  # about the centre of mass, mesh axes
    transform = np.eye(4)
    transform[:3, 3] = -com
    off_diagonal = np.abs(inertia - np.diag(np.diag(inertia))).max()
    if off_diagonal <= INERTIA_OFFDIAG_TOL * np.trace(inertia):
        return transform
    _, axes = np.linalg.eigh(inertia)  # columns: principal axes, ascending moments
    axes = axes * np.sign(axes[np.abs(axes).argmax(axis=0), np.arange(3)])  # deterministic signs
    if np.linalg.det(axes) < 0:
        axes[:, 2] *= -1.0
    rotation = axes.T  # rows: new x, y, z in mesh coordinates
    transform[:3, :3] = rotation
    transform[:3, 3] = -rotation @ com
    return transform


def principal_inertia(mesh: trimesh.Trimesh, mass_kg: float) -> np.ndarray:
    """Diagonal of the inertia tensor (kg m^2) about the origin for ``mass_kg`` spread uniformly in the mesh."""
    inertia = np.asarray(mesh.moment_inertia) * (mass_kg / mesh.mass)
    return np.diag(inertia).copy()


# ----------------------------------------------------------------------------- convex decompositions


def convex_parts_from_file(path: Path, transform: np.ndarray, scale: float) -> list[np.ndarray]:
    """Convex pieces of a shipped decomposition (e.g. ``duck_vhacd.obj``), in the object frame."""
    mesh = trimesh.load(str(path), force="mesh", process=False)
    mesh.apply_scale(scale)
    mesh.apply_transform(transform)
    return [piece.convex_hull.vertices for piece in mesh.split(only_watertight=False) if len(piece.vertices) >= 4]


def vhacd_parts(mesh: trimesh.Trimesh, resolution: int, max_vertices_per_hull: int) -> list[np.ndarray]:
    """Approximate convex decomposition with ``pybullet.vhacd``, run in a child process
    (V-HACD prints progress on the C stdout and can take a while; the child keeps both
    out of this process)."""
    with tempfile.TemporaryDirectory(prefix="multigrasp-vhacd-") as tmp:
        src, dst, log_file = Path(tmp) / "in.obj", Path(tmp) / "out.obj", Path(tmp) / "vhacd.log"
        mesh.export(str(src))
        code = (
            "import pybullet as p; c = p.connect(p.DIRECT); "
            f"p.vhacd({str(src)!r}, {str(dst)!r}, {str(log_file)!r}, resolution={int(resolution)}, "
            f"maxNumVerticesPerCH={int(max_vertices_per_hull)}, physicsClientId=c); p.disconnect(c)"
        )
        proc = subprocess.run([sys.executable, "-c", code], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, timeout=VHACD_TIMEOUT_S, check=False)
        if proc.returncode != 0 or not dst.exists():
            raise MultigraspError(f"pybullet.vhacd failed on a mesh (exit {proc.returncode}: {proc.stderr.decode(errors='replace')[-200:]}); try `repair: convex_hull` for this object")
        out = trimesh.load(str(dst), force="mesh", process=False)
    return [piece.convex_hull.vertices for piece in out.split(only_watertight=False) if len(piece.vertices) >= 4]


def parts_to_obj(parts: list[np.ndarray]) -> bytes:
    """Wavefront OBJ text with one ``o`` group per convex part (PyBullet loads it as a compound of hulls)."""
    lines: list[str] = []
    offset = 1
    for i, vertices in enumerate(parts):
        hull = trimesh.convex.convex_hull(vertices)
        lines.append(f"o part_{i}")
        lines.extend(f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in hull.vertices)
        lines.extend(f"f {a + offset} {b + offset} {c + offset}" for a, b, c in hull.faces)
        offset += len(hull.vertices)
    return ("\n".join(lines) + "\n").encode()


def parts_from_obj(data: bytes) -> list[np.ndarray]:
    """Inverse of :func:`parts_to_obj`: the vertices of each ``o`` group."""
    parts: list[list[list[float]]] = []
    for line in data.decode().splitlines():
        if line.startswith("o "):
            parts.append([])
        elif line.startswith("v ") and parts:
            parts[-1].append([float(x) for x in line.split()[1:4]])
    return [np.asarray(p) for p in parts if len(p) >= 4]


# ----------------------------------------------------------------------------- resting poses


def compute_stable_poses(mesh: trimesh.Trimesh, keep_mass: float, max_count: int) -> tuple[np.ndarray, np.ndarray]:
    """Resting poses on a table at z = 0 and their probabilities (trimesh.poses.compute_stable_poses).

    trimesh drops the convex hull from random orientations (quasi-statically, centre of mass
    at the object-frame origin) and returns, per resting facet, the transform that puts the
    object on the plane z = 0 and the probability of landing there. We keep the most probable
    poses that together hold ``keep_mass`` of the probability (at most ``max_count``) and
    renormalise. Returns ``(T (n, 4, 4), prob (n,))``, most probable first.
    """
    transforms, probs = trimesh.poses.compute_stable_poses(mesh, center_mass=np.zeros(3))
    order = np.argsort(-probs, kind="stable")
    transforms, probs = transforms[order], probs[order] / probs.sum()
    n_keep = min(int(np.searchsorted(np.cumsum(probs), keep_mass - 1e-12) + 1), max_count)
    transforms, probs = transforms[:n_keep], probs[:n_keep]
    return transforms, probs / probs.sum()


def narrowest_horizontal_width(hull_vertices: np.ndarray, rotation: np.ndarray) -> float:
    """Minimum width of the object's shadow on the table when rotated by ``rotation`` (3x3).

    Rotating calipers: the minimum over the 2-D hull's edge normals ``n`` of
    ``max(v . n) - min(v . n)`` — the smallest opening that can close around it horizontally.
    """
    xy = (hull_vertices @ rotation.T)[:, :2]  # (V, 2)
    hull = ConvexHull(xy)
    ring = xy[hull.vertices]  # (H, 2), counter-clockwise
    edges = np.roll(ring, -1, axis=0) - ring
    normals = np.stack([edges[:, 1], -edges[:, 0]], axis=1) / np.linalg.norm(edges, axis=1, keepdims=True)
    extents = ring @ normals.T  # (H, H)
    return float((extents.max(axis=0) - extents.min(axis=0)).min())

"""Contact candidates and keypoints of the hand, from the project's data files in ``assets/hand/``.

* ``contact_regions.yaml`` defines 17 palmar patches on collision geoms (the file's header explains
  the palmar side and the patch parameters).  :func:`region_points` lays ``n`` points on a patch with
  a golden-ratio lattice and returns them in the *link* frame, so the candidates move with FK.
* ``keypoints.yaml`` defines 31 points as (link, offset in the link frame).

Both loaders check names against the compiled model and raise :class:`MultigraspError` with the
file and the fix when a file is missing or inconsistent.
"""

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from components.errors import MultigraspError
from components.hand.mjcf import GeomSpec, HandSpec, quat_to_matrix

#: Project folder of the hand's data files (``assets/hand`` at the repository root).
DEFAULT_ASSETS_DIR = Path(__file__).resolve().parents[2] / "assets" / "hand"
#: Data file of the contact regions.
REGIONS_FILE = "contact_regions.yaml"
#: Data file of the keypoints.
KEYPOINTS_FILE = "keypoints.yaml"
#: 1 / golden ratio, the lattice's second-coordinate step.
INV_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0


@dataclass(frozen=True)
class LinkPoints:
    """Named points fixed on links: ``points[k]`` in the frame of ``link_names[k]``."""

    names: list  # (K,) region name of each point (contact candidates) or keypoint name
    link_names: list  # (K,)
    points: np.ndarray  # (K, 3) in the link frame
    normals: np.ndarray | None = None  # (K, 3) outward unit surface normals in the link frame (contact candidates)


def golden_lattice(n: int) -> np.ndarray:
    """n points of the unit square:  u_i = (i + 1/2) / n,  v_i = frac(1/2 + i / phi)  (phi: golden ratio).
    -> (n, 2)."""
    i = np.arange(n, dtype=np.float64)
    return np.stack([(i + 0.5) / n, np.mod(0.5 + i * INV_GOLDEN, 1.0)], axis=1)


def capsule_surface_points(half_length: float, radius: float, palmar: np.ndarray, axial: np.ndarray,
                           angle: np.ndarray) -> np.ndarray:
    """Points on a z-axis capsule centred at 0, at axial coordinate s and angle phi from ``palmar``.

    e(phi) = cos(phi) n + sin(phi) (z x n);   p = s z + rho(s) e(phi),
    rho(s) = r on the cylinder (|s| <= h) and sqrt(r^2 - (|s| - h)^2) on the end caps.
    palmar (3,) unit, perpendicular to z; axial, angle (n,) -> (n, 3) in the geom frame.
    """
    z = np.array([0.0, 0.0, 1.0])
    side = np.cross(z, palmar)
    cap = np.clip(np.abs(axial) - half_length, 0.0, radius)
    rho = np.sqrt(radius ** 2 - cap ** 2)
    direction = np.cos(angle)[:, None] * palmar + np.sin(angle)[:, None] * side  # (n, 3)
    return axial[:, None] * z + rho[:, None] * direction


def box_face_points(half_extents: np.ndarray, palmar: np.ndarray, extent_u: list, extent_v: list,
                    lattice: np.ndarray) -> np.ndarray:
    """Points on the box face with outward normal ``palmar`` (a signed box axis), at fractions of the
    half extents along the two other axes (x, y, z order):  p_k = h_k * lerp(extent, lattice).   -> (n, 3)."""
    axis = int(np.argmax(np.abs(palmar)))
    others = [k for k in range(3) if k != axis]
    points = np.zeros((len(lattice), 3))
    points[:, axis] = np.sign(palmar[axis]) * half_extents[axis]
    for k, extent, col in zip(others, (extent_u, extent_v), lattice.T):
        points[:, k] = half_extents[k] * (extent[0] + (extent[1] - extent[0]) * col)
    return points


def region_points(region: dict, geom: GeomSpec, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The n contact candidates of one region and their outward unit surface normals, in its link frame.
    -> (n, 3), (n, 3).  Capsule normals point from the nearest point of the axis segment to the point."""
    lattice = golden_lattice(n)
    palmar = np.asarray(region["palmar"], dtype=np.float64)
    if geom.kind == "capsule":
        axial = region["axial"][0] + (region["axial"][1] - region["axial"][0]) * lattice[:, 0]
        angle = np.deg2rad(region["half_angle_deg"]) * (2.0 * lattice[:, 1] - 1.0)
        rot = quat_to_matrix(geom.quat)
        palmar_geom = rot.T @ palmar
        palmar_geom[2] = 0.0  # keep it perpendicular to the capsule axis
        local = capsule_surface_points(geom.size[1], geom.size[0], palmar_geom / np.linalg.norm(palmar_geom),
                                       axial, angle)
        on_axis = np.zeros_like(local)
        on_axis[:, 2] = np.clip(local[:, 2], -geom.size[1], geom.size[1])
        normals = (local - on_axis) / np.linalg.norm(local - on_axis, axis=1, keepdims=True)
    elif geom.kind == "box":
        rot = quat_to_matrix(geom.quat)
        local = box_face_points(geom.size, rot.T @ palmar, region["extent_u"], region["extent_v"], lattice)
        face = rot.T @ palmar
        axis = int(np.argmax(np.abs(face)))
        normals = np.zeros_like(local)
        normals[:, axis] = np.sign(face[axis])
    else:
        raise MultigraspError(f"contact region {region['name']} is on a {geom.kind}: use a capsule or box geom")
    return local @ rot.T + geom.pos, normals @ rot.T


def _read_yaml(path: Path, key: str) -> list:
    """The list under ``key`` of a YAML file, with a one-line error when it is missing or malformed."""
    if not path.is_file():
        raise MultigraspError(f"missing hand data file {path}: restore it from the repository or fix hand.assets_dir")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise MultigraspError(f"{path} is not valid YAML ({exc}): fix the file") from exc
    if not isinstance(data, dict) or not isinstance(data.get(key), list):
        raise MultigraspError(f"{path} must hold a list under '{key}': fix the file")
    return data[key]


def load_contact_candidates(spec: HandSpec, assets_dir: Path, points_per_region: int) -> LinkPoints:
    """The contact candidates: ``points_per_region`` points on each region of contact_regions.yaml."""
    path = assets_dir / REGIONS_FILE
    geoms = {g.name: g for g in spec.collision_geoms}
    names, links, points, normals = [], [], [], []
    for region in _read_yaml(path, "regions"):
        geom = geoms.get(region.get("geom"))
        if geom is None or geom.body != region.get("link"):
            raise MultigraspError(f"{path}: region {region.get('name')} names geom {region.get('geom')} on link "
                                  f"{region.get('link')}, which the hand does not have: fix the file")
        names += [region["name"]] * points_per_region
        links += [region["link"]] * points_per_region
        region_pts, region_normals = region_points(region, geom, points_per_region)
        points.append(region_pts)
        normals.append(region_normals)
    return LinkPoints(names=names, link_names=links, points=np.concatenate(points, axis=0),
                      normals=np.concatenate(normals, axis=0))


def load_keypoints(spec: HandSpec, assets_dir: Path) -> LinkPoints:
    """The keypoints of keypoints.yaml."""
    path = assets_dir / KEYPOINTS_FILE
    bodies = {b.name for b in spec.bodies}
    entries = _read_yaml(path, "keypoints")
    for entry in entries:
        if entry.get("link") not in bodies or len(entry.get("offset", [])) != 3:
            raise MultigraspError(f"{path}: keypoint {entry.get('name')} needs a link of the hand and a 3-D offset: "
                                  f"fix the file")
    return LinkPoints(names=[e["name"] for e in entries], link_names=[e["link"] for e in entries],
                      points=np.array([e["offset"] for e in entries], dtype=np.float64))

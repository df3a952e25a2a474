"""Q1, the Ferrari-Canny grasp quality (paper §"Pre-Grasp Proposals"; DESIGN §6).

Definition used here, for one object O with centre of mass c and radius r (``ObjectModel.radius``):

* **Contacts**: the samples of the hand's *collision geometry* (capsules, boxes, forearm cylinder;
  :class:`components.synthesis.HandSurface`, spacing ``q1_hand_point_spacing_m``) whose signed distance to O
  is below ``contact_distance_m`` (5 mm; samples inside O count).  Each is projected onto the surface,
  x = h - d_O(h) n(h), with n the outward unit normal (SDF gradient).  With ``q1_solver='exact'`` all of
  them; with ``'capped'`` at most ``q1_max_contacts`` (farthest-point subset, starting from the closest
  sample), a lower bound of Q1 (the subset's hull lies inside the full one).  The hand's contact candidates are *not*
  used: any part of the hand that touches the object can push it.
  With ``q1_contact_mode='per_link'`` each hand link contributes at most one contact instead: its sample
  nearest O, if within ``contact_distance_m`` (the DexGraspNet / UniDexGrasp evaluation convention).
* **Primitive wrenches**: a friction cone of coefficient mu linearised by E edges (unit normal force),
  f_k = -n + mu (cos(2 pi k / E) t1 + sin(2 pi k / E) t2), and
  w_k = [f_k ; s (x - c) x f_k]  with s = 1 / r (torque normalised by the object's radius; default) or
  s = ``q1_torque_scale_per_m`` (1/m) when set.
* **Q1** = radius of the largest ball centred at the origin inside the convex hull W of all primitive
  wrenches = min over the facets of W of their distance to the origin (scipy / qhull, 6-D).  Q1 = 0 when
  there are no contacts, when the wrenches are rank-deficient (they cannot span the 6-D wrench space,
  e.g. one or two point contacts) or when the origin is not strictly inside W (no force closure).
  With every contact (``'exact'``) the hull has thousands of 6-D points, too many for qhull to take whole;
  :func:`q1_constraint_generation` gets the same value from the hull of a subset (first the farthest-point
  contacts' wrenches), adding the wrenches that lie beyond its nearest facets until the nearest facet has
  none beyond it: that facet then supports the hull of every wrench, so its distance is Q1 (the subset's
  hull lies inside the full one, so Q1 cannot be smaller).
* **Multi-object Q1** = min over the scene's objects.
* **Group Q1** (``q1_grasps(group=True)``, for grasps synthesised with ``fc_mode='group'``): the objects as one
  rigid body -- every object's contacts together, torques about the objects' centroid normalised by the
  group's bounding radius (``SceneObjects.bounding_radius``).  It assumes the objects' contacts with each
  other hold them together, so it bounds from above what the hand alone holds.
"""

from __future__ import annotations

import numpy as np
import torch
from scipy.spatial import ConvexHull, QhullError
from torch import Tensor

from components.hand import HandModel
from components.metrics.config import MetricsConfig
from components.objects.library import farthest_point_indices
from components.synthesis.hand_surface import HandSurface
from components.synthesis.scene_objects import SceneObjects

#: Components of a wrench: 3 of force, 3 of (normalised) torque.
WRENCH_DIM = 6
#: qhull attempts: scipy's default options, then joggled input ('QJ': coordinates perturbed by ~1e-11 of
#: their range), which avoids the topology errors that nearly coplanar cone edges raise in 6-D.
QHULL_OPTIONS = (None, "QJ")


def tangent_basis(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit tangents (t1, t2) with (t1, t2, n) orthonormal, per unit normal.   (C, 3) -> 2 x (C, 3)."""
    helper = np.where(np.abs(normals[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    t1 = np.cross(normals, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    return t1, np.cross(normals, t1)


def primitive_wrenches(points: np.ndarray, normals: np.ndarray, centre: np.ndarray, radius: float,
                       mu: float, n_edges: int, torque_scale: float | None = None) -> np.ndarray:
    """Edge wrenches of linearised friction cones (module docstring):
    f_k = -n + mu (cos a_k t1 + sin a_k t2),  w_k = [f_k ; s (x - c) x f_k],  s = 1 / r or ``torque_scale``.
    points, outward unit normals (C, 3) -> (C * E, 6)."""
    t1, t2 = tangent_basis(normals)
    angles = 2.0 * np.pi * np.arange(n_edges) / n_edges  # (E,)
    forces = (-normals[:, None, :] + mu * (np.cos(angles)[None, :, None] * t1[:, None, :]
                                           + np.sin(angles)[None, :, None] * t2[:, None, :]))  # (C, E, 3)
    scale = 1.0 / radius if torque_scale is None else torque_scale
    torques = np.cross((points - centre)[:, None, :], forces) * scale  # (C, E, 3)
    return np.concatenate([forces, torques], axis=-1).reshape(-1, WRENCH_DIM)


def q1_from_wrenches(wrenches: np.ndarray, rank_tolerance: float) -> float:
    """Q1 = min over facets of hull(W) of the facet's distance to the origin, 0 unless the origin is strictly
    inside a full-dimensional hull (module docstring).   wrenches (M, 6) -> float."""
    if len(wrenches) <= WRENCH_DIM:
        return 0.0
    singular = np.linalg.svd(wrenches, compute_uv=False)
    if singular[-1] <= rank_tolerance * singular[0]:
        return 0.0
    hull = _hull(wrenches)
    if hull is None:
        return 0.0
    # qhull facets: unit normal . x + offset <= 0 inside; the origin's distance to a facet is -offset
    return max(0.0, float(np.min(-hull.equations[:, -1])))


def _hull(wrenches: np.ndarray) -> ConvexHull | None:
    """qhull of the wrenches with the :data:`QHULL_OPTIONS` fallbacks; None if every attempt fails."""
    for options in QHULL_OPTIONS:
        try:
            return ConvexHull(wrenches, qhull_options=options)
        except QhullError:
            continue
    return None


#: A wrench counts as beyond a facet when it lies more than this (wrench units, O(1)) outside it: well above
#: qhull's round-off and the ~1e-11 joggle of 'QJ', well below any Q1 that matters.
BEYOND_TOLERANCE = 1e-9


def q1_constraint_generation(wrenches: np.ndarray, start: np.ndarray, rank_tolerance: float, rounds: int,
                             facets: int) -> tuple[float, int]:
    """Q1 of the hull of every wrench (M, 6) from hulls of subsets (module docstring), starting from the rows
    ``start`` (indices).  Each round: hull of the subset S; its facets (unit normal n, offset b: n . w + b <= 0
    inside) sorted by their distance -b to the origin; for the ``facets`` nearest, the wrench farthest beyond
    each joins S.  Stops when the nearest facet has no wrench beyond it (``BEYOND_TOLERANCE``): then
    Q1 = max(0, -b) -- the facet supports the full hull, and hull(S) lies inside it.  After ``rounds`` rounds
    (or if a subset's hull fails) the full hull is taken.  -> (Q1, rounds used)."""
    if len(wrenches) <= WRENCH_DIM:
        return 0.0, 0
    singular = np.linalg.svd(wrenches, compute_uv=False)
    if singular[-1] <= rank_tolerance * singular[0]:
        return 0.0, 0
    chosen = np.zeros(len(wrenches), dtype=bool)
    chosen[start] = True
    for used in range(1, rounds + 1):
        hull = _hull(wrenches[chosen]) if chosen.sum() > WRENCH_DIM else None
        if hull is None:
            break
        distance = -hull.equations[:, -1]
        nearest = np.argsort(distance)[:facets]
        beyond = wrenches @ hull.equations[nearest, :-1].T + hull.equations[nearest, -1]  # (M, k)
        worst = beyond.argmax(0)
        if beyond[worst[0], 0] <= BEYOND_TOLERANCE:
            return max(0.0, float(distance[nearest[0]])), used
        new = worst[beyond[worst, np.arange(len(nearest))] > BEYOND_TOLERANCE]
        chosen[new] = True
    return q1_from_wrenches(wrenches, rank_tolerance), rounds


def q1_single_object(points: np.ndarray, normals: np.ndarray, centre: np.ndarray, radius: float,
                     cfg: MetricsConfig) -> float:
    """Q1 of one object from its contact points and outward unit normals (C, 3) (module docstring).  With
    ``q1_solver='exact'`` and more than ``q1_exact_start`` contacts, the first ``q1_exact_start`` of them (the
    farthest-point subset :func:`object_contacts` puts first) start :func:`q1_constraint_generation`."""
    if len(points) == 0:
        return 0.0
    wrenches = primitive_wrenches(points, normals, centre, radius, cfg.friction_coefficient, cfg.friction_cone_edges,
                                  cfg.q1_torque_scale_per_m)
    if cfg.q1_solver == "exact" and len(points) > cfg.q1_exact_start:
        start = np.arange(cfg.q1_exact_start * cfg.friction_cone_edges)  # the starting contacts' cone edges
        return q1_constraint_generation(wrenches, start, cfg.q1_rank_tolerance, cfg.q1_exact_rounds,
                                        cfg.q1_exact_facets)[0]
    return q1_from_wrenches(wrenches, cfg.q1_rank_tolerance)


def q1_group(contacts: list[tuple[np.ndarray, np.ndarray]], centroid: np.ndarray, radius: float,
             cfg: MetricsConfig) -> float:
    """Group Q1 (module docstring): the (points, normals) of every object together, about ``centroid``, torques
    normalised by the group's bounding ``radius``."""
    return q1_single_object(np.concatenate([c for c, _ in contacts]), np.concatenate([n for _, n in contacts]),
                            centroid, radius, cfg)


def nearest_per_link(distances: np.ndarray, links: np.ndarray, candidates: np.ndarray) -> np.ndarray:
    """Of the sample indices ``candidates``, the one of lowest distance on each link (ties: the first).
    distances (M,), links (M,) -> indices (<= number of links,)."""
    order = candidates[np.lexsort((distances[candidates], links[candidates]))]  # by link, then distance
    first = np.ones(len(order), dtype=bool)
    first[1:] = links[order][1:] != links[order][:-1]
    return order[first]


def object_contacts(distances: np.ndarray, points: np.ndarray, normals: np.ndarray,
                    cfg: MetricsConfig, links: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The contacts of one grasp on one object: hand samples with d < ``contact_distance_m`` projected onto
    the surface, at most ``q1_max_contacts`` of them (farthest-point subset from the closest sample) with
    ``q1_solver='capped'``, all of them with the subset first with ``'exact'``, or with
    ``q1_contact_mode='per_link'`` the nearest such sample of each link (``links``: link index per sample).
    Samples whose SDF normal is undefined (norm <= 0.5) are skipped; the others are renormalised.
    distances (M,), points, normals (M, 3) -> (contact points (C, 3), normals (C, 3))."""
    norms = np.linalg.norm(normals, axis=1)
    # samples with no defined normal (zero SDF gradient, e.g. deep inside a grid SDF) cannot push: skipped
    touching = np.flatnonzero((distances < cfg.contact_distance_m) & (norms > 0.5))
    if len(touching) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    if cfg.q1_contact_mode == "per_link":
        if links is None:
            raise ValueError("q1_contact_mode='per_link' needs the link index of every hand sample")
        touching = nearest_per_link(distances, links, touching)
    normal = normals[touching] / norms[touching, None]
    surface = points[touching] - distances[touching, None] * normal
    subset = cfg.q1_exact_start if cfg.q1_solver == "exact" else cfg.q1_max_contacts
    if len(touching) > subset:
        chosen = farthest_point_indices(surface, subset, int(np.argmin(np.abs(distances[touching]))))
        if cfg.q1_solver == "exact":  # every contact, the starting subset first
            chosen = np.concatenate([chosen, np.setdiff1d(np.arange(len(surface)), chosen)])
        surface, normal = surface[chosen], normal[chosen]
    return surface, normal


def q1_grasps(hand: HandModel, objects: SceneObjects, p: Tensor, R: Tensor, q: Tensor, cfg: MetricsConfig,
              hand_surface: HandSurface | None = None, group: bool = False) -> tuple[Tensor, Tensor]:
    """Q1 of every grasp H = (p (B, 3), R (B, 3, 3), q (B, 22)) in the scene of ``objects``.
    -> (multi-object Q1 = min over objects (B,), or with ``group`` the group Q1 (module docstring),
    per object (B, n_obj)), float64 on the CPU."""
    samples = hand_surface if hand_surface is not None else HandSurface(hand, cfg.q1_hand_point_spacing_m)
    centres = objects.positions.double().cpu().numpy()
    radii = objects.radii.double().cpu().numpy()
    per_object = np.zeros((p.shape[0], objects.n_objects))
    grouped = np.zeros(p.shape[0])
    centroid, group_radius = objects.centroid.double().cpu().numpy(), objects.bounding_radius
    links = samples.link.cpu().numpy()
    with torch.no_grad():
        for start in range(0, p.shape[0], cfg.batch_chunk):
            rows = slice(start, start + cfg.batch_chunk)
            points = samples.world(hand, p[rows], R[rows], q[rows])  # (b, M, 3)
            dist, normal = objects.sdf_and_normal(points)  # (b, M, n_obj), (b, M, n_obj, 3)
            points, dist, normal = (t.double().cpu().numpy() for t in (points, dist, normal))
            for i in range(points.shape[0]):
                found = [object_contacts(dist[i, :, j], points[i], normal[i, :, j], cfg, links)
                         for j in range(objects.n_objects)]
                for j, (contacts, normals) in enumerate(found):
                    per_object[start + i, j] = q1_single_object(contacts, normals, centres[j], radii[j], cfg)
                if group:
                    grouped[start + i] = q1_group(found, centroid, group_radius, cfg)
    per_object_t = torch.as_tensor(per_object)
    return (torch.as_tensor(grouped) if group else per_object_t.amin(-1)), per_object_t

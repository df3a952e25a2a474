"""Analytic collision geometry of the hand: primitives, distance functions, self-penetration.

Primitives (from :mod:`components.hand.mjcf`): 16 capsules (the wrist and the 15 finger / thumb
segments), 3 boxes (palm0, palm1, lfmetacarpal) and, with the forearm, one cylinder (the bounding
cylinder of the forearm's convex mesh).

* A **capsule** is the set of points within ``r`` of the segment ``[a, b]``; the segment is the
  geom's local z axis, ``a, b = centre -+ half_length * z``.
* Boxes and the cylinder are handled as one family, the **prism**: a rectangle of half extents
  ``(h_x, h_y)`` rounded by ``rho`` in the local xy plane, extruded by ``+-h_z`` along z.  A box is
  the prism with ``rho = 0``, a cylinder the prism with ``h_x = h_y = 0, rho = r``; the prism
  distance (:func:`point_prism_signed_distance`) is exact for both, so one kernel and one line
  search serve all of them.

Sign convention: **negative inside**, positive outside, in metres (the opposite of DexGraspNet's
``cal_distance``, which returns penetration depth as a positive number).

Every distance is closed form except capsule-prism (self-penetration), which is *exact up to a line
search*: the signed distance to a convex set is convex, so ``min_t sd(a + t (b - a))`` is found by
golden-section search and the gradient is taken at the found ``t`` (envelope theorem:
d/dθ min_t f(t, θ) = ∂f/∂θ at t*).  Self-penetration needs only min(d, 0), so the search runs only on the pairs
that a Lipschitz lower bound from a few samples along the axis cannot rule out
(:func:`capsule_prism_penetrating_distance`; ~2 % of the pairs on generated grasps).

Self-collision pairs (:func:`self_collision_pairs`): geoms are grouped by the rigid body they ride on
(palm, wrist and forearm are one body while the wrist is held at 0).  A pair is checked unless both
geoms are on the same rigid body or one body is the other's *collision parent* -- its nearest
ancestor that carries collision geometry (the knuckle, thbase and thhub bodies carry none, so e.g.
ffproximal's collision parent is the palm and thmiddle's is thproximal).  Neighbours overlap at
their joints by design and MuJoCo does not collide parent and child either.  With this rule no
prism-prism pair remains (checked at construction).

Performance (the union distance is the hot path of synthesis): the nearest primitive of every
point is found without autograd by kernels written for memory traffic -- the Gram form for capsules
(two batched products, then a few in-place passes over geom-major (B, G, N) tensors) and one
batched product for every prism frame -- or, with ``compile_kernels``, by the plain broadcast
formulas fused by ``torch.compile``.  Only the winning primitive of each point is then re-evaluated
with autograd.  Points are re-centred on the hand before the Gram form to limit float32
cancellation (error ~1e-6 m for points within 0.3 m of the hand).
"""

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch
from torch import Tensor

from components.hand.mjcf import HandSpec, quat_to_matrix

#: 1 / golden ratio: the bracket shrink factor of golden-section search.
INV_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0


# ============================================================================ primitive distances
def smooth_norm(v: Tensor, *, eps: float) -> Tensor:
    """Euclidean norm with a finite gradient at 0:  |v|_eps = sqrt(|v|^2 + eps) - sqrt(eps).   (..., D) -> (...)."""
    return torch.sqrt((v * v).sum(-1) + eps) - math.sqrt(eps)


def point_segment_parameter(x: Tensor, a: Tensor, b: Tensor) -> Tensor:
    """Parameter of the point of segment [a, b] closest to x:  t* = clamp((x - a).(b - a) / |b - a|^2, 0, 1)."""
    ab = b - a
    return (((x - a) * ab).sum(-1) / (ab * ab).sum(-1)).clamp(0.0, 1.0)


def point_capsule_signed_distance(x: Tensor, a: Tensor, b: Tensor, radius: Tensor, *, eps: float) -> Tensor:
    """Signed distance from points to capsules (negative inside).

    d(x) = |x - a - t* (b - a)| - r   with t* from :func:`point_segment_parameter`.
    Shapes broadcast: x, a, b (..., 3), radius (...) -> (...).
    """
    t = point_segment_parameter(x, a, b).unsqueeze(-1)
    return smooth_norm(x - a - t * (b - a), eps=eps) - radius


def positive_part_norm(*components: Tensor, eps: float) -> Tensor:
    """|max(w, 0)| of a vector given by its components (smoothed like :func:`smooth_norm`).
    Written per component: reductions over an axis of size 2 or 3 are slow on CPU."""
    total = sum(c.clamp_min(0.0) ** 2 for c in components)
    return torch.sqrt(total + eps) - math.sqrt(eps)


def extrusion_signed_distance(d_section: Tensor, d_axial: Tensor, *, eps: float) -> Tensor:
    """Exact SDF of a 2-D shape extruded along z from the section SDF and w_z = |z| - h_z:
    w = (d_section, w_z);  d = |max(w, 0)| + min(max(w_1, w_2), 0)."""
    return (positive_part_norm(d_section, d_axial, eps=eps)
            + torch.maximum(d_section, d_axial).clamp_max(0.0))


def point_box_signed_distance(x_local: Tensor, half_extents: Tensor, *, eps: float) -> Tensor:
    """Signed distance from points, given in the box frame, to the box |x_k| <= h_k (negative inside).

    q = |x| - h;   d = |max(q, 0)| + min(max_k q_k, 0)      (the exact box SDF).
    Shapes broadcast: x_local (..., 3), half_extents (..., 3) -> (...).
    """
    qx, qy, qz = (x_local.abs() - half_extents).unbind(-1)
    return positive_part_norm(qx, qy, qz, eps=eps) + torch.maximum(torch.maximum(qx, qy), qz).clamp_max(0.0)


def point_cylinder_signed_distance(x_local: Tensor, radius: Tensor, half_length: Tensor, *, eps: float) -> Tensor:
    """Signed distance from points, given in the cylinder frame (axis z), to a capped cylinder.

    :func:`extrusion_signed_distance` of the disc:  d_section = sqrt(x^2 + y^2) - r,  w_z = |z| - h.
    Shapes broadcast: x_local (..., 3), radius, half_length (...) -> (...).
    """
    x, y, z = x_local.unbind(-1)
    radial = torch.sqrt(x * x + y * y + eps) - math.sqrt(eps) - radius
    return extrusion_signed_distance(radial, z.abs() - half_length, eps=eps)


def point_prism_signed_distance(x_local: Tensor, half_extents: Tensor, rounding: Tensor, *, eps: float) -> Tensor:
    """Signed distance from points, in the prism frame, to a rounded-rectangle prism (negative inside).

    Section: the rectangle |x| <= h_x, |y| <= h_y grown by rho:
    q = (|x| - h_x, |y| - h_y),  d_section = |max(q, 0)| + min(max(q), 0) - rho;  then
    :func:`extrusion_signed_distance` with w_z = |z| - h_z.  Exact for boxes (rho = 0) and cylinders
    (h_x = h_y = 0, rho = r).   x_local (..., 3), half_extents (..., 3), rounding (...) -> (...).
    """
    qx, qy, wz = (x_local.abs() - half_extents).unbind(-1)
    section = positive_part_norm(qx, qy, eps=eps) + torch.maximum(qx, qy).clamp_max(0.0) - rounding
    return extrusion_signed_distance(section, wz, eps=eps)


def segment_segment_closest_parameters(p1: Tensor, q1: Tensor, p2: Tensor, q2: Tensor, *,
                                       parallel_eps: float) -> tuple:
    """Parameters (s, t) of the closest points p1 + s d1 and p2 + t d2 of two segments (Ericson 5.1.9).

    With d1 = q1 - p1, d2 = q2 - p2, r = p1 - p2, a = d1.d1, e = d2.d2, b = d1.d2, c = d1.r, f = d2.r:
    s0 = clamp((b f - c e) / max(a e - b^2, eps), 0, 1),  t = clamp((b s0 + f) / e, 0, 1),
    s = clamp((b t - c) / a, 0, 1).
    Re-solving s for the clamped t always (Ericson keeps s0 when t needed no clamping) gives the same
    distance: at the constrained optimum s is the minimiser for that t.  For parallel segments
    (a e - b^2 ~ 0) any s0 in [0, 1] works: the two clamps project between the segments' intervals
    along their common line.  No boolean masks (``torch.where`` is ~30x slower than arithmetic on CPU).
    Segments must have non-zero length.  Shapes broadcast: (..., 3) -> (...), (...).
    """
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e = (d1 * d1).sum(-1), (d2 * d2).sum(-1)
    b, c, f = (d1 * d2).sum(-1), (d1 * r).sum(-1), (d2 * r).sum(-1)
    s = ((b * f - c * e) / (a * e - b * b).clamp_min(parallel_eps)).clamp(0.0, 1.0)
    t = ((b * s + f) / e).clamp(0.0, 1.0)
    s = ((b * t - c) / a).clamp(0.0, 1.0)
    return s, t


def capsule_capsule_signed_distance(p1: Tensor, q1: Tensor, r1: Tensor, p2: Tensor, q2: Tensor, r2: Tensor, *,
                                    eps: float, parallel_eps: float) -> Tensor:
    """Signed distance between capsules:  d = |p1 + s d1 - p2 - t d2| - r1 - r2  (s, t: closest segment points)."""
    s, t = segment_segment_closest_parameters(p1, q1, p2, q2, parallel_eps=parallel_eps)
    gap = p1 + s.unsqueeze(-1) * (q1 - p1) - p2 - t.unsqueeze(-1) * (q2 - p2)
    return smooth_norm(gap, eps=eps) - r1 - r2


def golden_section_minimiser(f: Callable[[Tensor], Tensor], shape: tuple, iterations: int,
                             like: Tensor) -> Tensor:
    """argmin over t in [0, 1] of a convex (unimodal) f, element-wise, by golden-section search.

    The bracket [lo, hi] keeps the minimiser; each iteration compares f at the interior points
    c = hi - g (hi - lo), d = lo + g (hi - lo) (g = 1 / golden ratio), keeps [lo, d] if f(c) < f(d)
    else [c, hi], and re-uses one of the two evaluations.  Returns the bracket's midpoint (shape).
    The branch is a 0/1 weight applied with ``lerp`` (boolean masks are ~30x slower on CPU).
    Runs without gradient: differentiate f at the returned t (envelope theorem).
    """
    with torch.no_grad():
        lo = torch.zeros(shape, dtype=like.dtype, device=like.device)
        hi = torch.ones_like(lo)
        c, d = hi - INV_GOLDEN * (hi - lo), lo + INV_GOLDEN * (hi - lo)
        fc, fd = f(c), f(d)
        for _ in range(iterations):
            left = (fd - fc).sign_().clamp_min_(0.0)  # 1 where f(c) < f(d): keep [lo, d]
            hi, lo = torch.lerp(hi, d, left), torch.lerp(c, lo, left)
            step = INV_GOLDEN * (hi - lo)
            new = torch.lerp(lo + step, hi - step, left)  # the one new interior point
            f_new = f(new)
            c, fc, d, fd = (torch.lerp(d, new, left), torch.lerp(fd, f_new, left),
                            torch.lerp(new, c, left), torch.lerp(f_new, fc, left))
        return 0.5 * (lo + hi)


def to_local(x: Tensor, centre: Tensor, rot: Tensor) -> Tensor:
    """Coordinates of x in a frame (centre, rot):  x_local = R^T (x - c).   x, centre (..., 3), rot (..., 3, 3)."""
    return ((x - centre).unsqueeze(-2) @ rot).squeeze(-2)


def capsule_convex_signed_distance(a: Tensor, b: Tensor, radius: Tensor, sdf: Callable[[Tensor], Tensor], *,
                                   iterations: int) -> Tensor:
    """Signed distance between a capsule and a convex shape with signed distance function ``sdf``:
    d = min_{t in [0,1]} sdf(a + t (b - a)) - r, the minimum found by :func:`golden_section_minimiser`.
    a, b (..., 3), radius (...) -> (...)."""

    def along(t: Tensor) -> Tensor:
        return sdf(a + t.unsqueeze(-1) * (b - a))

    t = golden_section_minimiser(along, a.shape[:-1], iterations, a)
    return along(t) - radius


def capsule_box_signed_distance(a: Tensor, b: Tensor, radius: Tensor, centre: Tensor, rot: Tensor,
                                half_extents: Tensor, *, iterations: int, eps: float) -> Tensor:
    """Signed distance between a capsule and a box:  d = min_t sd_box(R^T (a + t (b - a) - c)) - r
    (:func:`capsule_convex_signed_distance` on :func:`point_box_signed_distance`)."""
    a_loc, b_loc = to_local(a, centre, rot), to_local(b, centre, rot)
    return capsule_convex_signed_distance(a_loc, b_loc, radius,
                                          lambda x: point_box_signed_distance(x, half_extents, eps=eps),
                                          iterations=iterations)


def capsule_cylinder_signed_distance(a: Tensor, b: Tensor, radius: Tensor, centre: Tensor, rot: Tensor,
                                     cyl_radius: Tensor, cyl_half_length: Tensor, *, iterations: int,
                                     eps: float) -> Tensor:
    """Signed distance between a capsule and a cylinder:  d = min_t sd_cyl(R^T (a + t (b - a) - c)) - r."""
    a_loc, b_loc = to_local(a, centre, rot), to_local(b, centre, rot)
    return capsule_convex_signed_distance(
        a_loc, b_loc, radius, lambda x: point_cylinder_signed_distance(x, cyl_radius, cyl_half_length, eps=eps),
        iterations=iterations)


def capsule_prism_signed_distance(a: Tensor, b: Tensor, radius: Tensor, centre: Tensor, rot: Tensor,
                                  half_extents: Tensor, rounding: Tensor, *, iterations: int, eps: float) -> Tensor:
    """Signed distance between a capsule and a prism:  d = min_t sd_prism(R^T (a + t (b - a) - c)) - r."""
    a_loc, b_loc = to_local(a, centre, rot), to_local(b, centre, rot)
    return capsule_convex_signed_distance(
        a_loc, b_loc, radius, lambda x: point_prism_signed_distance(x, half_extents, rounding, eps=eps),
        iterations=iterations)


def capsule_prism_penetrating_distance(a: Tensor, b: Tensor, radius: Tensor, centre: Tensor, rot: Tensor,
                                       half_extents: Tensor, rounding: Tensor, *, iterations: int, samples: int,
                                       eps: float) -> Tensor:
    """min(d, 0) for capsule-prism pairs, d = :func:`capsule_prism_signed_distance`, line-searching only the pairs
    that can overlap.

    Screen: f(t) = sd_prism(a_loc + t (b_loc - a_loc)) is |b - a|-Lipschitz in t (the prism SDF is 1-Lipschitz),
    so with K = ``samples`` points t_k = k / (K - 1), every t is within 1 / (2 (K - 1)) of one of them and
    min_t f >= min_k f(t_k) - |b - a| / (2 (K - 1)).  Where that bound minus r is positive, d > 0 and min(d, 0) = 0
    (no gradient).  The remaining pairs get the golden-section search of :func:`capsule_convex_signed_distance`,
    as in :func:`capsule_prism_signed_distance`: their value and gradient are the full search's (up to float
    rounding).  a, b, centre (B, P, 3), radius, rounding (P,), rot (B, P, 3, 3), half_extents (P, 3) -> (B, P).
    """
    batch, n_pairs = a.shape[:2]
    a_loc, b_loc = to_local(a, centre, rot), to_local(b, centre, rot)  # (B, P, 3)
    with torch.no_grad():
        t = torch.linspace(0.0, 1.0, samples, dtype=a.dtype, device=a.device)[:, None]  # (K, 1)
        axis = b_loc - a_loc
        along = a_loc.unsqueeze(-2) + t * axis.unsqueeze(-2)  # (B, P, K, 3)
        nearest = point_prism_signed_distance(along, half_extents.unsqueeze(-2), rounding.unsqueeze(-1),
                                              eps=eps).amin(-1)  # (B, P)
        bound = nearest - axis.norm(dim=-1) / (2 * (samples - 1)) - radius
        index = (bound <= 0.0).reshape(-1).nonzero().squeeze(-1)  # (M,) flat (B P) indices that may overlap
    out = a.new_zeros(batch * n_pairs)
    if index.numel() == 0:
        return out.reshape(batch, n_pairs)

    def pick(x: Tensor, width: int) -> Tensor:  # (B, P, width) or (P, width) -> (M, width)
        return x.expand(batch, n_pairs, width).reshape(-1, width).index_select(0, index)

    pair_half, pair_rho = pick(half_extents, 3), pick(rounding.unsqueeze(-1), 1).squeeze(-1)
    dist = capsule_convex_signed_distance(
        pick(a_loc, 3), pick(b_loc, 3), pick(radius.unsqueeze(-1), 1).squeeze(-1),
        lambda x: point_prism_signed_distance(x, pair_half, pair_rho, eps=eps), iterations=iterations)
    return out.index_copy(0, index, dist.clamp_max(0.0)).reshape(batch, n_pairs)


# ============================================================================ batched nearest-primitive kernels
def homogeneous(x: Tensor, *extra: Tensor) -> Tensor:
    """[x, 1, extra...] along the last axis:  (B, N, 3) -> (B, N, 4 + len(extra))."""
    return torch.cat([x, torch.ones_like(x[..., :1]), *[e.unsqueeze(-1) for e in extra]], dim=-1)


def minimum_over_geoms(dist: Tensor, with_indices: bool) -> tuple:
    """min over the geom axis of (B, G, N) distances -> (values (B, N), indices (B, N) or None).
    (``amin`` is ~10x faster than ``min`` with indices on CPU: indices are computed only when asked.)"""
    if with_indices:
        return tuple(dist.min(dim=1))
    return dist.amin(dim=1), None


def nearest_capsule(x: Tensor, a: Tensor, b: Tensor, radius: Tensor, with_indices: bool = True) -> tuple:
    """Smallest signed distance from each point to a set of capsules, and the capsule that attains it (no grad).

    Gram form, two batched products (L = |ab|, w = ab / L):
    U = (x - a).w = [w, -a.w] . [x, 1],   |x - a|^2 = [-2a, |a|^2, 1] . [x, 1, |x|^2],
    T = clamp(U, 0, L) (the foot of the perpendicular, in metres along the axis),
    |x - a - T w|^2 = |x - a|^2 - 2 T U + T^2,   d = sqrt(max(., 0)) - r.
    Work tensors are geom-major (B, G, N) so every pass runs over contiguous points.
    x (B, N, 3), a, b (B, G, 3), radius (G,) -> values (B, N), indices (B, N) or None.
    """
    with torch.no_grad():
        centre = a.mean(dim=1, keepdim=True)  # (B, 1, 3): re-centre to limit float32 cancellation
        x, a, b = x - centre, a - centre, b - centre
        length = (b - a).norm(dim=-1, keepdim=True)  # (B, G, 1)
        w = (b - a) / length  # (B, G, 3)
        proj_map = torch.cat([w, -(a * w).sum(-1, keepdim=True)], dim=-1)  # (B, G, 4)
        dist_map = torch.cat([-2.0 * a, (a * a).sum(-1, keepdim=True), torch.ones_like(length)], dim=-1)  # (B, G, 5)
        xh = homogeneous(x, (x * x).sum(-1)).transpose(1, 2)  # (B, 5, N)
        proj = torch.bmm(proj_map, xh[:, :4])  # (B, G, N): U
        dist2 = torch.bmm(dist_map, xh)  # (B, G, N): |x - a|^2
        foot = torch.clamp(proj, min=torch.zeros_like(length), max=length)  # (B, G, N): T
        dist = dist2.addcmul_(foot, proj, value=-2.0).addcmul_(foot, foot).clamp_min_(0.0).sqrt_()
        return minimum_over_geoms(dist.sub_(radius[:, None]), with_indices)


def frames_local(x: Tensor, centre: Tensor, rot: Tensor) -> Tensor:
    """Every point in every primitive frame, x_local = R^T (x - c), as one product [R^T, -R^T c] . [x, 1].
    x (B, N, 3), centre (B, G, 3), rot (B, G, 3, 3) -> (B, G, 3, N) (geom-major, points contiguous)."""
    rot_t = rot.transpose(-1, -2)  # (B, G, 3, 3)
    rows = torch.cat([rot_t, -(rot_t @ centre.unsqueeze(-1))], dim=-1)  # (B, G, 3, 4)
    local = torch.bmm(rows.reshape(rot.shape[0], -1, 4), homogeneous(x).transpose(1, 2))  # (B, 3G, N)
    return local.reshape(rot.shape[0], rot.shape[1], 3, x.shape[1])


def nearest_prism(x: Tensor, centre: Tensor, rot: Tensor, half_extents: Tensor, rounding: Tensor,
                  with_indices: bool = True) -> tuple:
    """Smallest signed distance from each point to a set of prisms, and the prism that attains it (no grad).

    :func:`point_prism_signed_distance` evaluated in place, coordinate by coordinate (reductions over an
    axis of size 3 are slow on CPU), on geom-major tensors from :func:`frames_local`.
    x (B, N, 3), centre (B, G, 3), rot (B, G, 3, 3), half_extents (G, 3), rounding (G,)
    -> values (B, N), indices (B, N) or None.
    """
    with torch.no_grad():
        q = frames_local(x, centre, rot).abs_().sub_(half_extents[None, :, :, None])  # (B, G, 3, N)
        qx, qy, qz = q.unbind(2)  # 3 x (B, G, N)
        section = torch.maximum(qx, qy).clamp_max_(0.0)
        section.add_(qx.clamp_min(0.0).square_().add_(qy.clamp_min(0.0).square_()).sqrt_()).sub_(rounding[:, None])
        inside = torch.maximum(section, qz).clamp_max_(0.0)
        outside = section.clamp_min_(0.0).square_().add_(qz.clamp_min(0.0).square_()).sqrt_()
        return minimum_over_geoms(outside.add_(inside), with_indices)


def nearest_primitives_eager(x: Tensor, cap_a: Tensor, cap_b: Tensor, cap_r: Tensor, prism_c: Tensor,
                             prism_rot: Tensor, prism_h: Tensor, prism_rho: Tensor, eps: float,
                             with_indices: bool) -> list:
    """Nearest capsule and nearest prism of every point (eager kernels above; ``eps`` unused: no gradient).
    x (B, N, 3) -> [(values (B, N), indices (B, N) or None) for capsules, then prisms if any]."""
    found = [nearest_capsule(x, cap_a, cap_b, cap_r, with_indices)]
    if prism_c.shape[1]:
        found.append(nearest_prism(x, prism_c, prism_rot, prism_h, prism_rho, with_indices))
    return found


def nearest_primitives_direct(x: Tensor, cap_a: Tensor, cap_b: Tensor, cap_r: Tensor, prism_c: Tensor,
                              prism_rot: Tensor, prism_h: Tensor, prism_rho: Tensor, eps: float,
                              with_indices: bool) -> list:
    """Same result as :func:`nearest_primitives_eager`, written as the plain broadcast of the primitive
    formulas over (B, N, G): the form ``torch.compile`` fuses into one loop per kind (no (B, N, G)
    intermediate in memory).  Call it compiled, under ``torch.no_grad``."""
    found = [point_capsule_signed_distance(x[:, :, None], cap_a[:, None], cap_b[:, None], cap_r, eps=eps)]
    if prism_c.shape[1]:
        local = to_local(x[:, :, None], prism_c[:, None], prism_rot[:, None])  # (B, N, Gp, 3)
        found.append(point_prism_signed_distance(local, prism_h, prism_rho, eps=eps))
    if with_indices:
        return [tuple(d.min(dim=-1)) for d in found]
    return [(d.amin(dim=-1), None) for d in found]


# ============================================================================ the hand's primitives
def self_collision_pairs(spec: HandSpec, geoms: list) -> list:
    """Index pairs (i, j), i < j, of ``geoms`` that self-penetration checks (rule: module docstring)."""
    bodies = {b.name: b for b in spec.bodies}

    def rigid_body(name: str) -> str:  # the body a link is rigidly attached to (climb joint-less links)
        while bodies[name].joint is None and bodies[name].parent is not None:
            name = bodies[name].parent
        return name

    with_geoms = {rigid_body(g.body) for g in geoms}

    def collision_parent(group: str):  # nearest rigid ancestor that carries collision geoms
        node = bodies[group].parent
        while node is not None and rigid_body(node) not in with_geoms:
            node = bodies[rigid_body(node)].parent
        return None if node is None else rigid_body(node)

    pairs = []
    for i in range(len(geoms)):
        for j in range(i + 1, len(geoms)):
            gi, gj = rigid_body(geoms[i].body), rigid_body(geoms[j].body)
            if gi == gj or collision_parent(gi) == gj or collision_parent(gj) == gi:
                continue
            pairs.append((i, j))
    return pairs


@dataclass
class Primitives:
    """The hand's primitives posed in one frame (palm or world); B = batch."""

    capsule_a: Tensor  # (B, Gc, 3)
    capsule_b: Tensor  # (B, Gc, 3)
    prism_centre: Tensor  # (B, Gp, 3)
    prism_rot: Tensor  # (B, Gp, 3, 3)


class HandCollision:
    """The collision primitives of the hand stacked into tensors, with batched distance functions."""

    def __init__(self, spec: HandSpec, geoms: list, link_names: list, *, eps: float, parallel_eps: float,
                 iterations: int, screen_samples: int, compile_kernels: bool = False, device="cpu",
                 dtype=torch.float32):
        self.eps, self.parallel_eps, self.iterations = eps, parallel_eps, iterations
        self.screen_samples = screen_samples
        self._nearest = (torch.compile(nearest_primitives_direct, dynamic=False) if compile_kernels
                         else nearest_primitives_eager)
        link = {n: i for i, n in enumerate(link_names)}
        self.geoms = geoms
        self.geom_names = [g.name for g in geoms]
        self.capsule_ids = [i for i, g in enumerate(geoms) if g.kind == "capsule"]
        self.prism_ids = [i for i, g in enumerate(geoms) if g.kind != "capsule"]

        def tensor(values, shape) -> Tensor:
            return torch.tensor(np.array(values, dtype=np.float64).reshape(shape), dtype=dtype, device=device)

        def long(values) -> Tensor:
            return torch.tensor(values, dtype=torch.long, device=device)

        caps = [geoms[i] for i in self.capsule_ids]
        self.capsule_link = long([link[g.body] for g in caps])  # (Gc,)
        axis = [quat_to_matrix(g.quat)[:, 2] for g in caps]
        self.capsule_a_local = tensor([g.pos - g.size[1] * z for g, z in zip(caps, axis)], (-1, 3))  # (Gc, 3)
        self.capsule_b_local = tensor([g.pos + g.size[1] * z for g, z in zip(caps, axis)], (-1, 3))  # (Gc, 3)
        self.capsule_radius = tensor([g.size[0] for g in caps], (-1,))  # (Gc,)

        prisms = [geoms[i] for i in self.prism_ids]
        self.prism_link = long([link[g.body] for g in prisms])  # (Gp,)
        self.prism_centre_local = tensor([g.pos for g in prisms], (-1, 3))  # (Gp, 3)
        self.prism_rot_local = tensor([quat_to_matrix(g.quat) for g in prisms], (-1, 3, 3))  # (Gp, 3, 3)
        # box: (h_x, h_y, h_z), rho = 0;  cylinder: (0, 0, h), rho = r
        self.prism_half = tensor([g.size if g.kind == "box" else [0.0, 0.0, g.size[1]] for g in prisms], (-1, 3))
        self.prism_rounding = tensor([0.0 if g.kind == "box" else g.size[0] for g in prisms], (-1,))  # (Gp,)

        # self-collision pairs, capsule first, indexed within their kind
        slot = {i: k for ids in (self.capsule_ids, self.prism_ids) for k, i in enumerate(ids)}
        capsule_pairs, prism_pairs = [], []
        self.pair_names = []
        for i, j in self_collision_pairs(spec, geoms):
            if geoms[i].kind != "capsule":
                i, j = j, i
            if geoms[i].kind != "capsule":
                raise RuntimeError(f"no prism-prism distance for self-collision pair {geoms[i].name}, {geoms[j].name}")
            (capsule_pairs if geoms[j].kind == "capsule" else prism_pairs).append((slot[i], slot[j]))
        self.capsule_pairs = long(capsule_pairs).reshape(-1, 2)  # (Pc, 2) capsule, capsule
        self.prism_pairs = long(prism_pairs).reshape(-1, 2)  # (Pp, 2) capsule, prism
        self.pair_names = ([(caps[i].name, caps[j].name) for i, j in capsule_pairs]
                           + [(caps[i].name, prisms[j].name) for i, j in prism_pairs])  # pair_signed_distances order

    # ---------------------------------------------------------------- posing
    def pose(self, link_frames: Tensor) -> Primitives:
        """Pose every primitive with link frames (B, L, 4, 4) given in some frame F -> primitives in F."""
        cap_t = link_frames[:, self.capsule_link]  # (B, Gc, 4, 4)
        prism_t = link_frames[:, self.prism_link]  # (B, Gp, 4, 4)
        return Primitives(
            capsule_a=(cap_t[..., :3, :3] @ self.capsule_a_local.unsqueeze(-1)).squeeze(-1) + cap_t[..., :3, 3],
            capsule_b=(cap_t[..., :3, :3] @ self.capsule_b_local.unsqueeze(-1)).squeeze(-1) + cap_t[..., :3, 3],
            prism_centre=(prism_t[..., :3, :3] @ self.prism_centre_local.unsqueeze(-1)).squeeze(-1)
            + prism_t[..., :3, 3],
            prism_rot=prism_t[..., :3, :3] @ self.prism_rot_local,
        )

    # ---------------------------------------------------------------- distances
    def signed_distance(self, x: Tensor, prims: Primitives) -> Tensor:
        """Signed distance from points to the union of all primitives:  d(x) = min_g d_g(x).
        x (B, N, 3) in the primitives' frame -> (B, N).

        The nearest primitive of every point is found without autograd (:func:`nearest_primitives_eager`,
        or :func:`nearest_primitives_direct` compiled when ``compile_kernels``).  When a gradient is
        needed, only the winning primitive's distance is recomputed with autograd, once per point.
        The gradient of a minimum is the gradient of its minimiser, so this equals differentiating
        min_g d_g without any (B, N, G) tensor in the backward pass.
        """
        tensors = (x, prims.capsule_a, prims.capsule_b, prims.prism_centre, prims.prism_rot)
        needs_grad = torch.is_grad_enabled() and any(t.requires_grad for t in tensors)
        with torch.no_grad():
            found = self._nearest(x.detach(), prims.capsule_a.detach(), prims.capsule_b.detach(), self.capsule_radius,
                                  prims.prism_centre.detach(), prims.prism_rot.detach(), self.prism_half,
                                  self.prism_rounding, self.eps, needs_grad)
            values = torch.stack([d for d, _ in found])  # (kinds, B, N)
            if not needs_grad:
                return values.amin(0)
            best, kind = values.min(0)  # (B, N)

        batch, n_points = best.shape
        flat_x = x.reshape(-1, 3)  # (B N, 3)
        dist = x.new_zeros(batch * n_points)  # each point receives exactly one kind's value below
        for k in range(len(found)):
            point = (kind.reshape(-1) == k).nonzero().squeeze(-1)  # (M,) flat indices of the points kind k wins
            row = point // n_points  # (M,) batch index
            geom = found[k][1].reshape(-1).index_select(0, point)  # (M,) primitive within its kind
            xm = flat_x.index_select(0, point)  # (M, 3)
            if k == 0:
                n_geoms = prims.capsule_a.shape[1]
                a = prims.capsule_a.reshape(-1, 3).index_select(0, row * n_geoms + geom)
                b = prims.capsule_b.reshape(-1, 3).index_select(0, row * n_geoms + geom)
                d = point_capsule_signed_distance(xm, a, b, self.capsule_radius[geom], eps=self.eps)
            else:
                n_geoms = prims.prism_centre.shape[1]
                centre = prims.prism_centre.reshape(-1, 3).index_select(0, row * n_geoms + geom)
                rot = prims.prism_rot.reshape(-1, 3, 3).index_select(0, row * n_geoms + geom)
                d = point_prism_signed_distance(to_local(xm, centre, rot), self.prism_half[geom],
                                                self.prism_rounding[geom], eps=self.eps)
            dist = dist.index_add(0, point, d)
        return dist.reshape(batch, n_points)

    def capsule_pair_signed_distances(self, prims: Primitives) -> Tensor:
        """Signed distance of every capsule-capsule self-collision pair (closed form).   -> (B, Pc)."""
        a, b, r = prims.capsule_a, prims.capsule_b, self.capsule_radius
        i, j = self.capsule_pairs.unbind(-1)
        return capsule_capsule_signed_distance(a[:, i], b[:, i], r[i], a[:, j], b[:, j], r[j],
                                               eps=self.eps, parallel_eps=self.parallel_eps)

    def pair_signed_distances(self, prims: Primitives) -> Tensor:
        """Signed distance of every self-collision pair (``pair_names`` order).   -> (B, P)."""
        a, b, r = prims.capsule_a, prims.capsule_b, self.capsule_radius
        capsules = self.capsule_pair_signed_distances(prims)
        i, j = self.prism_pairs.unbind(-1)
        prisms = capsule_prism_signed_distance(a[:, i], b[:, i], r[i], prims.prism_centre[:, j], prims.prism_rot[:, j],
                                               self.prism_half[j], self.prism_rounding[j],
                                               iterations=self.iterations, eps=self.eps)
        return torch.cat([capsules, prisms], dim=1)

    def pair_penetrating_distances(self, prims: Primitives) -> Tensor:
        """min(d, 0) of every self-collision pair (``pair_names`` order): the signed distance of the pairs that
        overlap, 0 for the others -- all that relu(-d) (the self-penetration energy and depth) needs, with the
        capsule-prism pairs that cannot overlap screened out before their line search
        (:func:`capsule_prism_penetrating_distance`).   -> (B, P)."""
        a, b, r = prims.capsule_a, prims.capsule_b, self.capsule_radius
        capsules = self.capsule_pair_signed_distances(prims)
        i, j = self.prism_pairs.unbind(-1)
        prisms = capsule_prism_penetrating_distance(a[:, i], b[:, i], r[i], prims.prism_centre[:, j],
                                                    prims.prism_rot[:, j], self.prism_half[j], self.prism_rounding[j],
                                                    iterations=self.iterations, samples=self.screen_samples,
                                                    eps=self.eps)
        return torch.cat([capsules.clamp_max(0.0), prisms], dim=1)

    def self_penetration(self, prims: Primitives) -> Tensor:
        """Self-penetration energy:  E_spen = sum over checked pairs of relu(-d_pair).   -> (B,)."""
        return torch.relu(-self.pair_penetrating_distances(prims)).sum(-1)

    def lowest_heights(self, prims: Primitives) -> Tensor:
        """Height (z) of the lowest point of every primitive, in the primitives' frame -> (B, G), geoms order.

        capsule: min(a_z, b_z) - r;  prism (u = R^T e_z, the world z axis in the prism frame):
        c_z - (|u_x| h_x + |u_y| h_y + |u_z| h_z + rho sqrt(u_x^2 + u_y^2))  (support function).
        """
        batch = prims.capsule_a.shape[0]
        out = prims.capsule_a.new_zeros(batch, len(self.geoms))
        caps = torch.minimum(prims.capsule_a[..., 2], prims.capsule_b[..., 2]) - self.capsule_radius
        out = out.index_copy(1, self.capsule_link.new_tensor(self.capsule_ids), caps)
        if self.prism_ids:
            u = prims.prism_rot[..., 2, :]  # (B, Gp, 3)
            reach = (u.abs() * self.prism_half).sum(-1) + self.prism_rounding * smooth_norm(u[..., :2], eps=self.eps)
            out = out.index_copy(1, self.prism_link.new_tensor(self.prism_ids), prims.prism_centre[..., 2] - reach)
        return out

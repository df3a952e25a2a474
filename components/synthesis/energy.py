"""The multi-object DFC grasp energy (paper §"Preliminaries", Eq. multi-dfc-energy; DESIGN §5.1).

    E(H, O) = w_fc sum_j E_fc(x_j, O_j) + w_dist sum_j E_dist(x_j, O_j) + w_pen E_pen(H, O) + w_prior E_prior(H)
              [+ w_sur sum_j E_sur(H, O_j) + w_q1 sum_j E_q1(H, O_j) + w_opp sum_j E_opp(x_j, O_j)
               + w_align E_align + w_excess E_excess: options, off by default]

H = (p, R, q) is the hand pose, O_j the posed objects of the scene and x_j the ``contacts_per_object``
hand contact points assigned to object j (indices into ``HandModel.contact_candidates``; all distinct).
E_pen = w_po E_pen^obj-pts + w_ph E_pen^hand-pts + w_self E_spen + w_table E_table (the paper's
lambda_p E_p + lambda_sp E_sp; the table term is what makes the problem tabletop) and E_prior is the
paper's E_q.  The official MultiGrasp release uses the same four weights 1 / 10 / 10 / 10.

One equation per function below; :func:`energy` assembles them and returns the total with every named
term, per row (B,) and, where it is a sum over objects, per object (B, n_obj).  With ``fc_mode='group'`` the
w_fc term is one E_fc of all objects' contacts about their centroid (:func:`group_force_closure_error`), and
``fc_per_object`` repeats it for every object.  It also returns
detached *diagnostics* in metres (largest contact distance, deepest sampled penetration) for the filter.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import torch
from torch import Tensor

from components.errors import MultigraspError
from components.hand import HandModel
from components.hand.geometry import Primitives
from components.hand.model import palm_from_world, world_from_palm
from components.synthesis.config import SynthesisConfig
from components.synthesis.hand_surface import HandSurface
from components.synthesis.pose import unpack
from components.synthesis.scene_objects import SceneObjects

#: Hand geoms whose surface samples are *not* tested against the object SDFs in E_pen: the forearm
#: cylinder (r = 6.9 cm) and the wrist capsule are too large to slip between object surface samples,
#: and object points inside them are already caught by the exact hand SDF (E_pen^obj-pts).
LARGE_HAND_GEOMS = ("C_forearm", "C_wrist")
#: Key of the (B, K, 3) contact candidates in the dict returned by :func:`energy` (not an energy term).
CANDIDATE_POINTS = "candidate_points"
#: Key of the (B, n_obj, C) contact indices the energy used (the input ones, or with
#: ``contact_assignment='nearest'`` the ones it chose); not an energy term.
CONTACT_INDICES = "contact_indices"
#: Keys of :func:`energy`'s terms dict that are not per-row energies or diagnostics.
NON_TERM_KEYS = (CANDIDATE_POINTS, CONTACT_INDICES)


# ============================================================================ the energy's terms
def friction_tilted_forces(normals: Tensor, friction: float, iterations: int = 1) -> Tensor:
    """Unit contact forces tilted inside their friction cones to cancel the net force, ``iterations`` projection
    steps from f_i = n_i:

        r = sum_i f_i,   T_i <- T_i - (I - n_i n_i^T) r / C,   T_i <- T_i * min(1, mu / |T_i|),   f_i = n_i + T_i,

    i.e. each contact takes its share of the residual force along its tangent plane, its tangential part T_i
    at most mu times its (unit) normal force (Coulomb).  One step is the default; more steps hand on what a
    clamped contact could not take (three contacts +x, -x, +z of a box: residual 1/3 after one step, 1/3^k
    after k).  mu = 0 returns the normals (the official frictionless E_fc).
    normals (B, C, 3) -> forces (B, C, 3)."""
    if friction <= 0.0:
        return normals
    tangential = torch.zeros_like(normals)
    for _ in range(iterations):
        residual = (normals + tangential).sum(dim=1, keepdim=True)  # (B, 1, 3)
        normal_part = (residual * normals).sum(-1, keepdim=True) * normals  # (B, C, 3)
        tangential = tangential - (residual - normal_part) / normals.shape[1]
        norm = tangential.norm(dim=-1, keepdim=True)
        tangential = tangential * torch.clamp(friction / norm.clamp_min(1e-12), max=1.0)
    return normals + tangential


def contact_gate_weights(signed_distance: Tensor, scale: float) -> Tensor:
    """Proximity weights of the contacts in E_fc (``fc_contact_gate_m`` = s):

        g_i = exp(-|d_i| / s),   w_i = C g_i / sum_j g_j,

    so the C weights sum to C (all equal to 1 when the contacts are equally far) and a contact far from the
    surface, relative to the others, carries almost no force: E_fc is then the force-closure error of the
    contacts that touch, and a hovering contact cannot help it.  The weights are detached: through them the
    gradient would push contacts off the surface whenever dropping them lowers E_fc.  s <= 0 returns ones.
    (B, C) -> (B, C)."""
    if scale <= 0.0:
        return torch.ones_like(signed_distance)
    dist = signed_distance.detach().abs()
    g = torch.exp(-(dist - dist.amin(-1, keepdim=True)) / scale)
    return signed_distance.shape[-1] * g / g.sum(-1, keepdim=True)


def force_closure_error(points: Tensor, normals: Tensor, centre: Tensor, length: Tensor, margin: float,
                        friction: float = 0.0, weights: Optional[Tensor] = None, friction_iterations: int = 1) -> Tensor:
    """Force-closure error of one object (paper Eq. multi-dfc-energy, E_FC; DFC, Liu et al. 2021, Eq. 8b):

        E_fc = relu(|G f|^2 - margin),   G = [ I_3  ...  I_3 ; [x_1]x ... [x_C]x ]  (6 x 3C),
        |G f|^2 = |sum_i f_i|^2 + |sum_i x_i x f_i|^2,

    with f_i the contact force of unit normal component -- the object's outward unit normal n_i at contact
    i, tilted inside its friction cone of coefficient ``friction`` by :func:`friction_tilted_forces`
    (f_i = n_i when ``friction`` = 0, the official frictionless form) -- and x_i = (c_i - centre) / length
    its lever arm (length = the object's radius, or 1 m for the official raw coordinates).  Zero when
    the forces balance in force and torque (up to ``margin``).  Without friction three contacts on a
    box's faces can never balance (three axis-aligned unit vectors never sum to zero); with mu = 0.5 a
    pinch plus a third face contact does.  ``weights`` (B, C) (:func:`contact_gate_weights`) scale the
    forces f_i <- w_i f_i after the friction tilt; ``friction_iterations`` is the tilt's number of steps.
    points, normals (B, C, 3), centre (3,), length () -> (B,).
    """
    lever = (points - centre) / length  # (B, C, 3)
    forces = friction_tilted_forces(normals, friction, friction_iterations)
    if weights is not None:
        forces = forces * weights.unsqueeze(-1)
    force = forces.sum(dim=1)  # (B, 3)
    torque = torch.cross(lever, forces, dim=-1).sum(dim=1)  # (B, 3)
    return torch.relu((force * force).sum(-1) + (torque * torque).sum(-1) - margin)


def group_force_closure_error(problem: "GraspProblem", points: Tensor, normals: Tensor,
                              weights: Optional[Tensor] = None) -> Tensor:
    """Force-closure error of the objects held as one rigid body (``fc_mode='group'``):
    :func:`force_closure_error` over every object's contacts together, lever arms from the objects' centroid
    divided by ``problem.group_lever_length``,

        E_fc^group = relu(|sum_{j,i} f_ji|^2 + |sum_{j,i} x_ji x f_ji|^2 - margin),  x_ji = (c_ji - centroid) / L.

    points, normals (B, n_obj, C, 3) (normals: each object's outward unit normal at its contacts), weights
    (B, n_obj, C) or None -> (B,)."""
    cfg = problem.cfg
    batch = points.shape[0]
    return force_closure_error(points.reshape(batch, -1, 3), normals.reshape(batch, -1, 3), problem.objects.centroid,
                               problem.group_lever_length, cfg.fc_margin, cfg.fc_friction,
                               None if weights is None else weights.reshape(batch, -1), cfg.fc_friction_iterations)


def contact_distance_energy(signed_distance: Tensor) -> Tensor:
    """Contact distance of one object (DESIGN §5.1, E_dist):  E_dist = sum_i |d_O(c_i)|  (m), the distance
    of each assigned hand contact point to the object's surface.   (B, C) -> (B,)."""
    return signed_distance.abs().sum(-1)


def contact_excess_energy(signed_distance: Tensor, tolerance: float) -> Tensor:
    """Hinge on the contact distance beyond a tolerance h (``contact_excess_m``):

        E_excess = sum_i (relu(|d_O(c_i)| - h) / h)^2      (dimensionless),

    zero for contacts within h of the surface and quadratic beyond, so a contact hovering a few h off the
    surface costs more than any force-closure error it could buy through the SDF normal of its off-surface
    point (E_dist is linear in |d| and, at the official weight 10, a 1 cm hover costs 0.1).
    h <= 0 returns zeros.   (B, C) -> (B,)."""
    if tolerance <= 0.0:
        return torch.zeros_like(signed_distance[..., 0])
    return (torch.relu(signed_distance.abs() - tolerance) / tolerance).square().sum(-1)


def contact_alignment_energy(hand_normals: Tensor, object_normals: Tensor) -> Tensor:
    """Contact alignment of one object (the official release's ``normal_alignment``, there unweighted):
        E_align = sum_i (1 + n_H(c_i) . n_O(c_i)),
    n_H the hand surface's outward normal at contact candidate i and n_O the object's outward normal there:
    0 when the hand touches the object with the patch's face (opposed normals), 2 when the patch faces away
    -- pulling such a contact onto the surface drives the finger through the object.   (B, C, 3) x2 -> (B,)."""
    return (1.0 + (hand_normals * object_normals).sum(-1)).sum(-1)


def opposition_weight(cfg: SynthesisConfig, w_fc: float) -> float:
    """E_opp's weight in a stage whose force-closure weight is ``w_fc``: ``w_opposition`` x w_fc / cfg.w_fc, so it
    is off wherever E_fc is (the approach) and follows E_fc's MALA ramp."""
    if cfg.w_opposition <= 0 or cfg.w_fc <= 0:
        return 0.0
    return cfg.w_opposition * w_fc / cfg.w_fc


def contact_opposition_energy(normals: Tensor, threshold: float) -> Tensor:
    """Contact opposition of one object (``w_opposition``; not in the official release):

        E_opp = relu(tau - max_{i<k} -m_i . m_k),     tau = ``opposition_min``,

    m_i the unit normal at contact i (the object's outward normal, or the hand patch's: -m_i . m_k is the same
    for both when they face each other).  0 when two of the contacts push from sides more than arccos(-tau)
    apart (tau 0.5: 120 deg, the 'opposed' of ``benchmarks.lift_failures``), 1 + tau when they all push the same
    way.  The max passes its gradient to the best pair only.   normals (B, C, 3) -> (B,)."""
    cosines = (normals.unsqueeze(2) * normals.unsqueeze(1)).sum(-1)  # (B, C, C)
    count = normals.shape[1]
    upper = torch.triu(torch.ones(count, count, dtype=torch.bool, device=normals.device), diagonal=1)
    best = (-cosines[:, upper]).amax(-1) if count > 1 else torch.full_like(normals[:, 0, 0], -1.0)
    return torch.relu(threshold - best)


def object_points_in_hand(hand_signed_distance: Tensor) -> Tensor:
    """Object-into-hand penetration (paper E_p, first half):  E = sum_k relu(-d_H(o_k))  (m), over the
    object surface samples o_k, with d_H the hand's signed distance (negative inside a primitive).
    (..., P) -> (...)."""
    return torch.relu(-hand_signed_distance).sum(-1)


def hand_points_in_objects(object_signed_distance: Tensor) -> Tensor:
    """Hand-into-object penetration (paper E_p, second half):  E_j = sum_m relu(-d_{O_j}(h_m))  (m), over
    the hand surface samples h_m.   (B, M, n_obj) -> (B, n_obj)."""
    return torch.relu(-object_signed_distance).sum(1)


def surround_energy(points: Tensor, distances: Tensor, normals: Tensor, centres: Tensor, lengths: Tensor,
                    band: float) -> Tensor:
    """Force balance over every hand sample touching an object (``w_surround``), per object j:

        w_i = relu(1 - |d_j(h_i)| / band),     x_i = h_i - d_j(h_i) n_i,     u_i = [-n_i ; (x_i - c_j) x (-n_i) / L_j]
        E_sur,j = | sum_i w_i u_i |^2 / (sum_i w_i + 1)^2

    over the hand surface samples h_i (E_pen's), with n_i the object's outward normal (detached) and x_i the
    sample projected onto the surface: the squared length of the mean unit push wrench of the samples within
    ``band`` of the surface (0 when they push from around the object, ~1-2 when all push from one side; the
    +1 keeps a lone grazing sample from counting fully).  E_fc balances only the chosen contacts; Q1 counts
    every touching sample, and grasps whose touching samples push from one side score Q1 ~ 0 (the length of
    their mean normal has Spearman -0.64 with Q1 on the bench Pl pairs).
    points (B, M, 3), distances (B, M, n_obj), normals (B, M, n_obj, 3), centres (n_obj, 3), lengths (n_obj,)
    -> (B, n_obj)."""
    weights = torch.relu(1.0 - distances.abs() / band).unsqueeze(-1)  # (B, M, n_obj, 1)
    surface = points.unsqueeze(2) - distances.unsqueeze(-1) * normals  # (B, M, n_obj, 3)
    push = -normals
    torque = torch.cross((surface - centres) / lengths.unsqueeze(-1), push, dim=-1)
    force_sum, torque_sum = (weights * push).sum(1), (weights * torque).sum(1)  # (B, n_obj, 3)
    count = weights.squeeze(-1).sum(1)  # (B, n_obj)
    return ((force_sum * force_sum).sum(-1) + (torque_sum * torque_sum).sum(-1)) / (count + 1.0) ** 2


def wrench_directions(n: int, seed: int, dtype: torch.dtype = torch.float32, device: str | torch.device = "cpu") -> Tensor:
    """``n`` fixed unit directions u = (u_f, u_tau) of the 6-D wrench space (Gaussian draws normalised, seeded), at
    which :func:`q1_surrogate` probes the support of the wrench hull.  -> (n, 6)."""
    generator = torch.Generator().manual_seed(seed)
    u = torch.randn(n, 6, generator=generator, dtype=torch.float64)
    return (u / u.norm(dim=-1, keepdim=True)).to(dtype=dtype, device=device)


def wrench_support(arm: Tensor, normals: Tensor, directions: Tensor, friction: float) -> Tensor:
    """Support s_k(u) = max over contact k's wrenches w = [f ; a_k x f] of u . w, for its circular friction cone
    f = -n_k + mu t (|t| <= 1, t . n_k = 0):  with v = u_f + u_tau x a_k,  s_k(u) = -v.n_k + mu |v - (v.n_k) n_k|.
    arm (B, K, 3) lever arms a_k (over the radius), normals (B, K, 3), directions (B, D, 6) -> (B, K, D)."""
    u_force, u_torque = directions[..., :3], directions[..., 3:]  # (B, D, 3) x2
    # v.n = u_f.n + u_tau.(a x n);  |v|^2 = |u_f|^2 + 2 a.(u_f x u_tau) + |u_tau|^2 |a|^2 - (u_tau.a)^2
    v_n = (torch.einsum("bkc,bdc->bkd", normals, u_force)
           + torch.einsum("bkc,bdc->bkd", torch.cross(arm, normals, dim=-1), u_torque))
    u_t_a = torch.einsum("bkc,bdc->bkd", arm, u_torque)
    v_sq = ((u_force * u_force).sum(-1).unsqueeze(1)
            + 2.0 * torch.einsum("bkc,bdc->bkd", arm, torch.cross(u_force, u_torque, dim=-1))
            + (u_torque * u_torque).sum(-1).unsqueeze(1) * (arm * arm).sum(-1, keepdim=True) - u_t_a * u_t_a)
    return -v_n + friction * torch.sqrt(torch.relu(v_sq - v_n * v_n) + 1e-12)


def hull_support(arm: Tensor, normals: Tensor, weight: Tensor, directions: Tensor, friction: float) -> Tensor:
    """S(u) = max_k c_k s_k(u) over the samples with c_k > 0 (-1 where there are none).  -> (B, D)."""
    support = weight.unsqueeze(-1) * wrench_support(arm, normals, directions, friction)  # (B, K, D)
    return torch.where((weight > 0).unsqueeze(-1), support, support.new_tensor(-1.0)).amax(1)


def weakest_directions(arm: Tensor, normals: Tensor, weight: Tensor, start: Tensor, friction: float,
                       steps: int, smoothing: float, rate: float, decay: float) -> Tensor:
    """The directions ``start`` (B, m, 6) -- the weakest of the fixed ones -- each moved by ``steps`` projected
    gradient steps (step ``rate``, times ``decay`` after each) down the smoothed support
    ``smoothing`` log sum_k exp(c_k s_k(u) / ``smoothing``) on the unit sphere (no autograd through the result):
    the fixed directions alone miss narrow gaps of the hull (two opposing contacts, which resist no torque about
    their axis, read 0.08 with 4,096 random directions), and steps down the unsmoothed max converge slowly.
    -> (B, m, 6)."""
    with torch.enable_grad():
        arm, normals, weight, u = arm.detach(), normals.detach(), weight.detach(), start.detach()
        touching = (weight > 0).unsqueeze(-1)
        for _ in range(steps):
            u = u.requires_grad_(True)
            support = weight.unsqueeze(-1) * wrench_support(arm, normals, u, friction)
            support = torch.where(touching, support, support.new_tensor(-1.0))
            smooth = smoothing * torch.logsumexp(support / smoothing, dim=1)  # (B, m)
            (grad,) = torch.autograd.grad(smooth.sum(), u)
            with torch.no_grad():
                grad = grad - (grad * u).sum(-1, keepdim=True) * u
                u = u - rate * grad
                u = u / u.norm(dim=-1, keepdim=True).clamp_min(1e-12)
            rate *= decay
    return u.detach()


def q1_surrogate(points: Tensor, distances: Tensor, normals: Tensor, centre: Tensor, radius: Tensor,
                 directions: Tensor, band: float, friction: float, temperature: float,
                 keep: int = 8, steps: int = 15, smoothing: float = 0.02, rate: float = 0.5,
                 decay: float = 0.85) -> Tensor:
    """A smooth Ferrari-Canny Q1 of one object (``w_q1``), over the hand samples h_k nearest it:

        c_k = relu(1 - |d_k| / band)          (1 on the surface, 0 beyond the band -- Q1's contact distance -- or as deep)
        x_k = h_k - d_k n_k,   a_k = (x_k - c) / r              (projected on the surface; lever arm over the radius)
        S(u) = max_k c_k s_k(u)   (:func:`wrench_support`; samples with c_k = 0 excluded, S = -1 if none)
        Q1~ = -T log sum_{u in U} exp(-S(u) / T)

    S(u) is the support of the hull of every contact's circular friction cone of wrenches, and min_u S(u) over all
    unit u is the radius of the largest origin-centred ball inside that hull -- the metric's Q1 (with circular
    cones instead of its ``friction_cone_edges``-gons, and c_k shrinking the wrenches of samples near the band's
    edges: the metric counts samples inside the object as contacts, but a surrogate that did would pay the grasp to
    sink in -- on cube + cylinder, seed 0, w_q1 100, earlier versions of the term: PN 3.5 mm with c_k = 1 inside,
    3.0 mm with this weight, 1.8 mm without the term).  U = the fixed
    ``directions`` (D, 6) plus the ``keep`` weakest of them refined by ``steps`` gradient steps
    (:func:`weakest_directions`); the soft minimum over U is a lower bound of min_U S, negative when the
    origin is outside the hull (no force closure), which keeps a gradient there.  n_k is detached; the gradient
    moves the samples onto the surface (c_k) and along it (a_k).
    points (B, K, 3), distances (B, K), normals (B, K, 3), centre (3,), radius () -> (B,)."""
    weight = torch.relu(1.0 - distances.abs() / band)  # (B, K)
    surface = points - distances.unsqueeze(-1) * normals
    arm = (surface - centre) / radius  # (B, K, 3)
    hull = hull_support(arm, normals, weight, directions.expand(points.shape[0], -1, -1), friction)  # (B, D)
    if keep > 0:  # the weakest fixed directions, searched further (their support at the start is reused, not redone)
        start = directions[hull.detach().topk(min(keep, directions.shape[0]), dim=-1, largest=False).indices]
        searched = weakest_directions(arm, normals, weight, start, friction, steps, smoothing, rate, decay)
        hull = torch.cat([hull, hull_support(arm, normals, weight, searched, friction)], dim=-1)  # (B, D + keep)
    return -temperature * torch.logsumexp(-hull / temperature, dim=-1)


def q1_surrogate_energy(problem: "GraspProblem", samples: Tensor, distances: Tensor) -> Tensor:
    """E_q1 per object (``w_q1``):  E_q1,j = relu(q1_target - Q1~_j), Q1~ of :func:`q1_surrogate` over the
    ``q1_samples`` hand samples nearest object j's surface (E_pen's samples ``samples`` (B, M, 3) and their signed
    distances (B, M, n_obj), differentiable within ``q1_band_m``).  -> (B, n_obj)."""
    cfg, objects = problem.cfg, problem.objects
    k = min(cfg.q1_samples, samples.shape[1])
    out = []
    for j in range(objects.n_objects):
        nearest = torch.topk(-distances[..., j].detach().abs(), k, dim=1).indices  # (B, k) nearest the surface
        points = torch.gather(samples, 1, nearest.unsqueeze(-1).expand(-1, -1, 3))
        dist = torch.gather(distances[..., j], 1, nearest)
        with torch.no_grad():
            normals = objects.object_sdf_and_normal(j, points.detach())[1]
        q1 = q1_surrogate(points, dist, normals, objects.positions[j], objects.radii[j], problem.q1_directions,
                          cfg.q1_band_m, cfg.q1_friction, cfg.q1_temperature, cfg.q1_weakest, cfg.q1_weakest_steps,
                          cfg.q1_search_smoothing, cfg.q1_search_rate, cfg.q1_search_decay)
        out.append(torch.relu(cfg.q1_target - q1))
    return torch.stack(out, dim=-1)


def table_penetration(lowest_heights: Tensor, table_height: float) -> Tensor:
    """Hand below the table (DESIGN §5.1):  E_table = sum_g relu(z_table - z_g)  (m), z_g the height of the
    lowest point of hand primitive g (exact support function).   (B, G) -> (B,)."""
    return torch.relu(table_height - lowest_heights).sum(-1)


def self_penetration_energy(pair_signed_distances: Tensor) -> Tensor:
    """Self-penetration (paper E_sp):  E_spen = sum over checked geom pairs of relu(-d_pair)  (m)
    (pairs: ``HandModel.self_penetration``); the signed distances or, as :func:`penetration` passes them,
    min(d, 0) (``HandCollision.pair_penetrating_distances``), which gives the same value.   (B, P) -> (B,)."""
    return torch.relu(-pair_signed_distances).sum(-1)


def joint_limit_energy(hand: HandModel, q: Tensor) -> Tensor:
    """Joint-limit prior (paper E_q):  E_prior = sum_j relu(q_j - upper_j) + relu(lower_j - q_j)  (rad).
    (B, 22) -> (B,)."""
    return hand.joint_limit_violation(q)


# ============================================================================ fixed inputs of one scene
@dataclass
class GraspProblem:
    """What the energy of one scene needs besides the pose: the hand, the posed objects, fixed samples."""

    hand: HandModel
    objects: SceneObjects
    cfg: SynthesisConfig
    hand_surface: HandSurface  # samples tested against the object SDFs (large geoms excluded)
    object_points: Tensor  # (n_obj, P, 3) world surface samples tested against the hand SDF
    lever_lengths: Tensor  # (n_obj,) torque normalisation of E_fc
    group_lever_length: Tensor  # () torque normalisation of the group E_fc (fc_mode='group')
    q1_directions: Tensor  # (D, 6) wrench directions of E_q1 (``q1_directions``)

    @classmethod
    def build(cls, hand: HandModel, objects: SceneObjects, cfg: SynthesisConfig) -> "GraspProblem":
        n_contacts = objects.n_objects * cfg.contacts_per_object
        n_candidates = len(hand.contact_region_of)
        if n_contacts >= n_candidates:
            raise MultigraspError(
                f"{objects.n_objects} objects x synthesis.contacts_per_object={cfg.contacts_per_object} contacts need more "
                f"than the hand's {n_candidates} contact candidates; lower contacts_per_object or raise hand.contact_points_per_region")
        check_excluded_regions(hand.region_names, cfg)
        lengths = objects.radii if cfg.fc_normalize_by_radius else torch.ones_like(objects.radii)
        group_length = objects.radii.new_tensor(objects.bounding_radius if cfg.fc_normalize_by_radius else 1.0)
        return cls(hand=hand, objects=objects, cfg=cfg,
                   hand_surface=HandSurface(hand, cfg.hand_point_spacing_m, exclude=LARGE_HAND_GEOMS),
                   object_points=objects.surface_points(cfg.object_surface_points, cfg.seed_surface_points),
                   lever_lengths=lengths, group_lever_length=group_length,
                   q1_directions=wrench_directions(cfg.q1_directions, cfg.seed_surface_points, objects.radii.dtype,
                                                   objects.radii.device))

    @property
    def finger_of(self) -> Tensor:
        """Finger of every contact candidate (K,) long: regions share a finger when their names share the
        prefix before '_' (``ff_distal`` -> ``ff``), the palm's regions all count as ``palm``."""
        names = [n.split("_")[0] for n in self.hand.region_names]
        fingers = list(dict.fromkeys(names))
        region_finger = torch.tensor([fingers.index(n) for n in names], device=self.hand.contact_region_of.device)
        return region_finger[self.hand.contact_region_of]

    @property
    def candidate_allowed(self) -> Optional[Tensor]:
        """Candidates that may be chosen as contacts (K,) bool: those outside ``contact_regions_excluded``
        (None when nothing is excluded, so callers skip the mask)."""
        if not self.cfg.contact_regions_excluded:
            return None
        names = self.hand.region_names
        excluded = torch.tensor([n in self.cfg.contact_regions_excluded for n in names],
                                device=self.hand.contact_region_of.device)
        return ~excluded[self.hand.contact_region_of]

    @property
    def n_candidates(self) -> int:
        return len(self.hand.contact_region_of)

    def effective_joints(self, q: Tensor) -> Tensor:
        """The joint angles the energy sees: with ``couple_distal_joints`` the J0 of FF/MF/RF/LF follow J1."""
        return self.hand.expand_actuated(self.hand.actuated(q)) if self.cfg.couple_distal_joints else q


def check_excluded_regions(region_names: list, cfg: SynthesisConfig) -> None:
    """One-line :class:`MultigraspError` when ``contact_regions_excluded`` names a region the hand does not have,
    or leaves fewer fingers than one object's contacts need (the palm counts as one finger)."""
    unknown = sorted(set(cfg.contact_regions_excluded) - set(region_names))
    if unknown:
        raise MultigraspError(f"synthesis.optimizer.contact_regions_excluded: unknown hand region(s) {unknown}; "
                              f"the regions are {list(region_names)}")
    fingers = {n.split("_")[0] for n in region_names if n not in cfg.contact_regions_excluded}
    if len(fingers) < cfg.contacts_per_object:
        raise MultigraspError(f"synthesis.optimizer.contact_regions_excluded leaves {len(fingers)} finger(s) "
                              f"({sorted(fingers)}) for contacts_per_object={cfg.contacts_per_object} contacts on "
                              f"distinct fingers; exclude fewer regions")


def assignment_scores(problem: "GraspProblem", points: Tensor, hand_normals: Tensor) -> Tensor:
    """score_jk = |d_j(c_k)| + a * (1 + n_H(c_k) . n_j(c_k)) / 2 (a = ``assign_align_scale_m``): how well hand
    candidate k would serve as a contact of object j (m).   points, hand_normals (B, K, 3) -> (B, n_obj, K)."""
    with torch.no_grad():
        d, n = problem.objects.sdf_and_normal(points)  # (B, K, n_obj), (B, K, n_obj, 3)
        facing = (hand_normals.unsqueeze(2) * n).sum(-1)  # (B, K, n_obj)
        return (d.abs() + problem.cfg.assign_align_scale_m * (1.0 + facing) / 2.0).transpose(1, 2)


def region_contacts(problem: "GraspProblem", contacts: Tensor, points: Tensor, hand_normals: Tensor) -> Tensor:
    """``contact_assignment='region'``: every contact moves to the candidate of its own hand region with the
    lowest :func:`assignment_scores` for its object.   contacts (B, n_obj, C) -> (B, n_obj, C) long."""
    region_of = problem.hand.contact_region_of  # (K,)
    score = assignment_scores(problem, points, hand_normals)  # (B, n_obj, K)
    same = region_of[contacts].unsqueeze(-1) == region_of  # (B, n_obj, C, K)
    masked = score.unsqueeze(2).masked_fill(~same, float("inf"))
    return masked.argmin(-1)


def nearest_contacts(problem: "GraspProblem", points: Tensor, hand_normals: Tensor) -> Tensor:
    """Contacts chosen from the pose (``contact_assignment='nearest'``): for object j and candidate k

        score_jk = |d_j(c_k)| + a * (1 + n_H(c_k) . n_j(c_k)) / 2,     a = ``assign_align_scale_m``,

    each finger f (``GraspProblem.finger_of``; the palm is one) offers its best candidate
    k_jf = argmin_{k on f} score_jk, and object j takes the ``contacts_per_object`` fingers with the lowest
    score_{j k_jf} -- so one object's contacts sit on distinct fingers (fingers may touch several objects).
    Piecewise constant in the pose: the gradient flows through the chosen points, not the choice.
    points, hand_normals (B, K, 3) -> contacts (B, n_obj, C) long."""
    cfg = problem.cfg
    finger_of = problem.finger_of
    n_fingers = int(finger_of.max()) + 1
    score = assignment_scores(problem, points, hand_normals)  # (B, n_obj, K)
    if (allowed := problem.candidate_allowed) is not None:  # excluded regions never win
        score = score.masked_fill(~allowed, float("inf"))
    with torch.no_grad():
        best_score, best_index = [], []
        for f in range(n_fingers):
            members = (finger_of == f).nonzero().squeeze(-1)  # (K_f,)
            value, arg = score[..., members].min(-1)  # (B, n_obj)
            best_score.append(value)
            best_index.append(members[arg])
        best_score, best_index = torch.stack(best_score, -1), torch.stack(best_index, -1)  # (B, n_obj, F)
        chosen = best_score.topk(cfg.contacts_per_object, dim=-1, largest=False).indices  # (B, n_obj, C)
        return best_index.gather(-1, chosen)


def best_contacts(problem: "GraspProblem", points: Tensor, hand_normals: Tensor, contacts: Tensor,
                  w_fc: Optional[float] = None, w_dist: Optional[float] = None,
                  w_align: Optional[float] = None) -> Tensor:
    """FC-aware reassignment of the contacts for a fixed pose (``contact_reassign_every``): the conditional
    mode of the contact-dependent part of E over a small candidate set.  For object j (in order):

    1. every finger f (``GraspProblem.finger_of``, the palm is one) offers its candidate of lowest
       :func:`assignment_scores` k_jf, among candidates no earlier object took;
    2. every set S of ``contacts_per_object`` distinct fingers is scored by
       e_j(S) = w_fc E_fc(S) + w_dist sum_{k in S} |d_j(c_k)| + w_align E_align(S)
       (the terms of E that depend on the contacts; E_pen and E_prior depend on the pose only);
    3. object j takes the best set, unless its current contacts score lower (a row's energy never rises).

    Candidates of ``contact_regions_excluded`` are never offered, and a set with a finger that has no allowed
    candidate left scores +inf.

    ``w_fc`` / ``w_dist`` / ``w_align`` override the config's weights (MALA ramp, refinement, approach).
    points, hand_normals (B, K, 3) (detached), contacts (B, n_obj, C) -> (B, n_obj, C) long."""
    import itertools

    objects, cfg = problem.objects, problem.cfg
    w_fc = cfg.w_fc if w_fc is None else w_fc
    w_dist = cfg.w_dist if w_dist is None else w_dist
    w_align = cfg.w_align if w_align is None else w_align
    w_opposition = opposition_weight(cfg, w_fc)
    finger_of = problem.finger_of
    n_fingers, per = int(finger_of.max()) + 1, cfg.contacts_per_object
    batch, n_cand = points.shape[:2]
    sets = torch.tensor(list(itertools.combinations(range(n_fingers), per)), device=points.device)  # (T, C)
    out = contacts.clone()
    taken = torch.zeros(batch, n_cand, dtype=torch.bool, device=points.device)
    if (allowed := problem.candidate_allowed) is not None:  # excluded candidates count as taken from the start
        taken |= ~allowed.unsqueeze(0)
    rows = torch.arange(batch, device=points.device)

    def score(j: int, index: Tensor) -> Tensor:  # index (B, T, C) -> e_j (B, T)
        n_sets = index.shape[1]
        pts = points.gather(1, index.reshape(batch, -1, 1).expand(-1, -1, 3)).reshape(batch * n_sets, per, 3)
        nrm = hand_normals.gather(1, index.reshape(batch, -1, 1).expand(-1, -1, 3)).reshape(batch * n_sets, per, 3)
        d, n = objects.object_sdf_and_normal(j, pts)
        gate = contact_gate_weights(d, cfg.fc_contact_gate_m) if cfg.fc_contact_gate_m > 0 else None
        e = (w_fc * force_closure_error(pts, n, objects.positions[j], problem.lever_lengths[j], cfg.fc_margin,
                                        cfg.fc_friction, gate, cfg.fc_friction_iterations)
             + w_dist * contact_distance_energy(d) + w_align * contact_alignment_energy(nrm, n)
             + cfg.w_contact_excess * contact_excess_energy(d, cfg.contact_excess_m))
        if w_opposition > 0:
            e = e + w_opposition * contact_opposition_energy(n if cfg.opposition_normals == "object" else nrm,
                                                             cfg.opposition_min)
        return e.reshape(batch, n_sets)

    with torch.no_grad():
        d_all, n_all = objects.sdf_and_normal(points)  # (B, K, n_obj), (B, K, n_obj, 3)
        for j in range(objects.n_objects):
            assign = d_all[..., j].abs() + cfg.assign_align_scale_m * (1.0 + (hand_normals * n_all[:, :, j]).sum(-1)) / 2.0
            assign = assign.masked_fill(taken, float("inf"))  # (B, K)
            best, open_ = [], []
            for f in range(n_fingers):
                members = (finger_of == f).nonzero().squeeze(-1)
                value, arg = assign[:, members].min(-1)
                best.append(members[arg])
                open_.append(torch.isfinite(value))
            best, open_ = torch.stack(best, -1), torch.stack(open_, -1)  # (B, F)
            options = best[:, sets]  # (B, T, C)
            e_sets = score(j, options).masked_fill(~open_[:, sets].all(-1), float("inf"))
            value, arg = e_sets.min(-1)  # (B,)
            current = score(j, out[:, j].unsqueeze(1)).squeeze(1)
            clash = taken.gather(1, out[:, j]).any(-1)  # current contacts taken by an earlier object
            use = (value < current) | clash
            out[:, j] = torch.where(use.unsqueeze(-1), options[rows, arg], out[:, j])
            taken.scatter_(1, out[:, j], True)
    return out


def posed_in_world(prims: Primitives, p: Tensor, R: Tensor) -> Primitives:
    """Palm-frame primitives moved to the world by (p, R):  x_w = R x + p,  rot_w = R rot."""
    def move(x: Tensor) -> Tensor:  # (B, G, 3)
        return x @ R.transpose(1, 2) + p.unsqueeze(1)

    return Primitives(capsule_a=move(prims.capsule_a), capsule_b=move(prims.capsule_b),
                      prism_centre=move(prims.prism_centre), prism_rot=R.unsqueeze(1) @ prims.prism_rot)


def gather_contacts(candidates: Tensor, contacts: Tensor) -> Tensor:
    """Contact points of every object.   candidates (B, K, 3), contacts (B, n_obj, C) -> (B, n_obj, C, 3)."""
    batch, n_obj, n_c = contacts.shape
    flat = contacts.reshape(batch, n_obj * n_c, 1).expand(-1, -1, 3)
    return candidates.gather(1, flat).reshape(batch, n_obj, n_c, 3)


def object_points_hand_distances(hand: HandModel, points: Tensor, p: Tensor, R: Tensor, prims: Primitives) -> Tensor:
    """Hand signed distance d_H of world points (B, N, 3) -> (B, N), differentiable where it matters.

    Every point's distance is found without autograd; only the points inside the hand (d < 0, padded to
    the row with the most of them) are re-evaluated with autograd.  The points outside keep their
    detached value: every penetration term is relu(-d), whose value and gradient vanish there, so the
    energy and its gradient are those of the dense evaluation at a fraction of the backward cost.
    With ``HandConfig.compile_distance_kernels`` the dense evaluation is used (compiled kernels are
    specialised to one shape; the inside points change shape every step).
    """
    palm = palm_from_world(points, p, R)  # (B, N, 3)
    if hand.cfg.compile_distance_kernels:  # compiled kernels are built per shape: keep the one dense shape
        return hand.collision.signed_distance(palm, prims)
    with torch.no_grad():
        dist = hand.collision.signed_distance(palm, prims)  # (B, N)
    inside = dist < 0.0
    counts = inside.sum(1)  # (B,)
    n_max = int(counts.max()) if counts.numel() else 0
    if n_max == 0 or not torch.is_grad_enabled():
        return dist
    order = torch.argsort((~inside).to(torch.int8), dim=1, stable=True)[:, :n_max]  # (B, n_max) inside first
    valid = torch.arange(n_max, device=dist.device) < counts.unsqueeze(1)  # (B, n_max)
    chosen = palm.gather(1, order.unsqueeze(-1).expand(-1, -1, 3))  # (B, n_max, 3)
    redone = hand.collision.signed_distance(chosen, prims)  # (B, n_max) with autograd
    redone = torch.where(valid, redone, dist.gather(1, order))  # padding keeps the detached value
    return dist.scatter(1, order, redone)


def hand_points_object_distances(objects: SceneObjects, points: Tensor, band: float = 0.0) -> Tensor:
    """Object signed distances of hand points (B, M, 3) -> (B, M, n_obj), differentiable where it matters:
    as :func:`object_points_hand_distances`, only the points inside some object (or within ``band`` of
    one, for :func:`surround_energy`) are re-evaluated with autograd."""
    with torch.no_grad():
        dist = objects.sdf(points)  # (B, M, n_obj)
    if not torch.is_grad_enabled():
        return dist
    flat = dist.reshape(-1, dist.shape[-1])  # (B M, n_obj)
    index = (flat < band).any(-1).nonzero().squeeze(-1)  # (K,)
    if index.numel() == 0:
        return dist
    redone = objects.sdf(points.reshape(1, -1, 3)[:, index]).squeeze(0)  # (K, n_obj) with autograd
    return flat.index_copy(0, index, redone).reshape(dist.shape)


# ============================================================================ the total
@dataclass
class Penetration:
    """The penetration terms of a batch of hand poses (see :func:`penetration`): per-part energies (m) and
    their weighted total ``pen`` (B,) (differentiable), and the deepest sampled depths (detached, m)."""

    object_points: Tensor  # (B, n_obj)  object surface samples inside the hand
    hand_points: Tensor  # (B, n_obj)  hand surface samples inside each object
    self_: Tensor  # (B,)
    table: Tensor  # (B,)
    pen: Tensor  # (B,)  w_po * sum + w_ph * sum + w_self * self + w_table * table
    depth_objects: Tensor  # (B, n_obj)
    depth_table: Tensor  # (B,)
    depth_self: Tensor  # (B,)
    hand_samples: Tensor  # (B, M, 3)  the hand surface samples in the world
    hand_distances: Tensor  # (B, M, n_obj)  their object signed distances (differentiable inside / near)

    @property
    def depth_max(self) -> Tensor:
        """Deepest sampled penetration of any kind (B,)."""
        return torch.maximum(torch.maximum(self.depth_objects.amax(-1), self.depth_table), self.depth_self)


def penetration(problem: GraspProblem, p: Tensor, R: Tensor, frames: Tensor, prims: Primitives,
                band: float = 0.0) -> Penetration:
    """E_pen = w_po E_pen^obj-pts + w_ph E_pen^hand-pts + w_self E_spen + w_table E_table (module docstring) of
    poses (p, R) with palm-frame link ``frames`` and collision ``prims`` (from the FK of the pose's joints).
    Only points found inside (hand samples: or within ``band`` of an object) are re-evaluated with autograd
    (:func:`object_points_hand_distances`, :func:`hand_points_object_distances`)."""
    cfg, hand, objects = problem.cfg, problem.hand, problem.objects
    batch = p.shape[0]
    n_obj, n_pts = problem.object_points.shape[:2]
    obj_pts = problem.object_points.reshape(1, n_obj * n_pts, 3).expand(batch, -1, -1)  # (B, n_obj P, 3)
    d_hand = object_points_hand_distances(hand, obj_pts, p, R, prims).reshape(batch, n_obj, n_pts)
    hand_samples = problem.hand_surface.from_frames(world_from_palm(p, R, frames))  # (B, M, 3)
    d_obj = hand_points_object_distances(objects, hand_samples, band)
    pairs = hand.collision.pair_penetrating_distances(prims)  # (B, P) min(d, 0): relu(-d) is all it needs
    lowest = hand.collision.lowest_heights(posed_in_world(prims, p, R))  # (B, G)
    object_points, hand_points = object_points_in_hand(d_hand), hand_points_in_objects(d_obj)  # (B, n_obj) x2
    self_, table = self_penetration_energy(pairs), table_penetration(lowest, objects.table_height)
    pen = (cfg.w_pen_object_points * object_points.sum(-1) + cfg.w_pen_hand_points * hand_points.sum(-1)
           + cfg.w_pen_self * self_ + cfg.w_pen_table * table)
    with torch.no_grad():
        depth_objects = torch.maximum(torch.relu(-d_hand).amax(-1), torch.relu(-d_obj).amax(1))  # (B, n_obj)
        depth_table = torch.relu(objects.table_height - lowest).amax(-1)
        depth_self = torch.relu(-pairs).amax(-1) if pairs.shape[1] else torch.zeros_like(depth_table)
    return Penetration(object_points, hand_points, self_, table, pen, depth_objects, depth_table, depth_self,
                       hand_samples, d_obj)


def near_normals(objects: SceneObjects, points: Tensor, distances: Tensor, band: float) -> Tensor:
    """Detached outward normals (B, M, n_obj, 3) of every object at the hand samples ``points`` (B, M, 3) that
    lie within ``band`` of some object (``distances`` (B, M, n_obj)); zero elsewhere (their weight in
    :func:`surround_energy` is 0)."""
    normals = points.new_zeros(*distances.shape, 3)
    near = (distances.abs() < band).any(-1)  # (B, M)
    if bool(near.any()):
        with torch.no_grad():
            normals[near] = objects.sdf_and_normal(points[near].unsqueeze(0))[1].squeeze(0)
    return normals


def penetration_energy(problem: GraspProblem, p: Tensor, R: Tensor, q: Tensor,
                       frames: Optional[Tensor] = None) -> tuple[Tensor, Tensor]:
    """E_pen (B,) (differentiable) and the deepest sampled penetration (B,) (detached, m) of hand poses
    p (B, 3), R (B, 3, 3), q (B, 22) -- :func:`penetration` after the FK (generator refinement, reaching);
    ``frames`` = ``hand.forward_kinematics(q)`` when the caller has it already."""
    frames = problem.hand.forward_kinematics(q) if frames is None else frames
    result = penetration(problem, p, R, frames, problem.hand.collision.pose(frames))
    return result.pen, result.depth_max


def energy(problem: GraspProblem, x: Tensor, contacts: Tensor, w_dist: Optional[float] = None,
           w_fc: Optional[float] = None, w_align: Optional[float] = None,
           w_surround: Optional[float] = None, w_q1: Optional[float] = None) -> tuple[Tensor, dict]:
    """E(H, O) of the module docstring for flat poses x (B, 31) (:mod:`components.synthesis.pose`) and
    contacts (B, n_obj, C).  ``w_dist`` overrides ``cfg.w_dist`` (the refinement raises it), ``w_fc``
    overrides ``cfg.w_fc`` (the MALA ramp of ``w_fc_ramp_fraction``; 0 in the approach stage), ``w_align``
    overrides ``cfg.w_align`` (0 in the approach stage), ``w_surround`` overrides ``cfg.w_surround`` (0 in the
    approach stage), ``w_q1`` overrides ``cfg.w_q1`` (0 in the approach stage).

    Returns (total (B,), terms) with terms: ``fc``, ``dist``, ``pen``, ``prior``, ``surround``, ``q1``, ``opposition``
    (unweighted, (B,); E_opp enters the total with :func:`opposition_weight`);
    ``fc_per_object``, ``dist_per_object``, ``pen_object_points``, ``pen_hand_points`` ((B, n_obj));
    ``pen_self``, ``pen_table`` ((B,)); diagnostics (detached, m): ``contact_distance_max``,
    ``penetration_depth_objects``, ``penetration_depth_table``, ``penetration_depth_self``,
    ``penetration_depth_max``, ``contact_distance_per_object`` (mean |d| of each object's contacts, (B, n_obj));
    ``candidate_points`` (B, K, 3): every contact candidate in the world (for guided contact switches) and
    ``contact_indices`` (B, n_obj, C): the contacts used (``NON_TERM_KEYS``: not energy terms, dropped from results).
    """
    cfg, hand, objects = problem.cfg, problem.hand, problem.objects
    w_dist = cfg.w_dist if w_dist is None else w_dist
    w_fc = cfg.w_fc if w_fc is None else w_fc
    w_align = cfg.w_align if w_align is None else w_align
    w_surround = cfg.w_surround if w_surround is None else w_surround
    w_q1 = cfg.w_q1 if w_q1 is None else w_q1
    p, R, q_param = unpack(x)
    q = problem.effective_joints(q_param)  # (B, 22)

    frames = hand.forward_kinematics(q)  # (B, L, 4, 4) palm frame
    prims = hand.collision.pose(frames)  # palm frame

    # contacts: E_fc and E_dist per object
    candidate_points, candidate_normals = hand.contact_candidates_and_normals(p, R, q)  # (B, K, 3) x2
    if cfg.contact_assignment == "nearest":
        contacts = nearest_contacts(problem, candidate_points.detach(), candidate_normals.detach())
    elif cfg.contact_assignment == "region":
        contacts = region_contacts(problem, contacts, candidate_points.detach(), candidate_normals.detach())
    contact_points = gather_contacts(candidate_points, contacts)  # (B, n_obj, C, 3)
    contact_normals = gather_contacts(candidate_normals, contacts)
    fc, dist, align, excess, contact_dist, surface_normals, gates, opposition = [], [], [], [], [], [], [], []
    for j in range(objects.n_objects):
        d, n = objects.object_sdf_and_normal(j, contact_points[:, j])  # (B, C), (B, C, 3)
        gate = contact_gate_weights(d, cfg.fc_contact_gate_m) if cfg.fc_contact_gate_m > 0 else None
        if cfg.fc_mode == "per_object":
            fc.append(force_closure_error(contact_points[:, j], n, objects.positions[j], problem.lever_lengths[j],
                                          cfg.fc_margin, cfg.fc_friction, gate, cfg.fc_friction_iterations))
        surface_normals.append(n)
        gates.append(gate)
        dist.append(contact_distance_energy(d))
        excess.append(contact_excess_energy(d, cfg.contact_excess_m))
        align.append(contact_alignment_energy(contact_normals[:, j], n))
        opposition.append(contact_opposition_energy(n if cfg.opposition_normals == "object" else contact_normals[:, j],
                                                    cfg.opposition_min))
        contact_dist.append(d.detach().abs())
    if cfg.fc_mode == "group":
        fc_group = group_force_closure_error(problem, contact_points, torch.stack(surface_normals, dim=1),
                                             None if gates[0] is None else torch.stack(gates, dim=1))
        fc = [fc_group] * objects.n_objects  # every object reports the group's error (the filter's max is it)
    fc_per_object, dist_per_object = torch.stack(fc, dim=-1), torch.stack(dist, dim=-1)  # (B, n_obj)
    align_per_object = torch.stack(align, dim=-1)

    band = max(cfg.surround_band_m if w_surround > 0 else 0.0, cfg.q1_band_m if w_q1 > 0 else 0.0)
    pen_terms = penetration(problem, p, R, frames, prims, band)
    pen = pen_terms.pen
    if w_surround > 0:
        normals = near_normals(objects, pen_terms.hand_samples.detach(), pen_terms.hand_distances.detach(), band)
        surround = surround_energy(pen_terms.hand_samples, pen_terms.hand_distances, normals, objects.positions,
                                   problem.lever_lengths, band).sum(-1)
    else:
        surround = torch.zeros_like(pen)
    if w_q1 > 0:
        q1_term = q1_surrogate_energy(problem, pen_terms.hand_samples, pen_terms.hand_distances).sum(-1)
    else:
        q1_term = torch.zeros_like(pen)

    prior = joint_limit_energy(hand, q)
    fc_total = fc_group if cfg.fc_mode == "group" else fc_per_object.sum(-1)
    dist_total = dist_per_object.sum(-1)
    excess_total = torch.stack(excess, dim=-1).sum(-1)
    align_total = align_per_object.sum(-1)
    opposition_total = torch.stack(opposition, dim=-1).sum(-1)
    w_opposition = opposition_weight(cfg, w_fc)
    total = (w_fc * fc_total + w_dist * dist_total + cfg.w_pen * pen + cfg.w_prior * prior
             + w_align * align_total + cfg.w_contact_excess * excess_total + w_surround * surround + w_q1 * q1_term)
    if w_opposition > 0:  # E_opp is always reported (a ~0.05 ms diagnostic per object at B 256), added only when on
        total = total + w_opposition * opposition_total

    with torch.no_grad():
        terms = {
            "fc": fc_total, "dist": dist_total, "pen": pen, "prior": prior, "align": align_total, "excess": excess_total,
            "surround": surround, "q1": q1_term, "opposition": opposition_total,
            "fc_per_object": fc_per_object, "dist_per_object": dist_per_object,
            "pen_object_points": pen_terms.object_points, "pen_hand_points": pen_terms.hand_points,
            "pen_self": pen_terms.self_, "pen_table": pen_terms.table,
            "contact_distance_max": torch.cat(contact_dist, dim=-1).amax(-1),
            "penetration_depth_objects": pen_terms.depth_objects, "penetration_depth_table": pen_terms.depth_table,
            "penetration_depth_self": pen_terms.depth_self, "penetration_depth_max": pen_terms.depth_max,
            "contact_distance_per_object": torch.stack(contact_dist, dim=1).mean(-1),
            CANDIDATE_POINTS: candidate_points.detach(), CONTACT_INDICES: contacts,
        }
    return total, terms


def energy_and_grad(problem: GraspProblem, x: Tensor, contacts: Tensor,
                    w_dist: Optional[float] = None, w_fc: Optional[float] = None,
                    w_align: Optional[float] = None,
                    w_surround: Optional[float] = None, w_q1: Optional[float] = None) -> tuple[Tensor, Tensor, dict]:
    """Energy (B,), its gradient wrt x (B, D) and the detached terms.  Rows are independent, so the
    gradient of the batch sum is every row's own gradient."""
    with torch.enable_grad():
        x = x.detach().requires_grad_(True)
        total, terms = energy(problem, x, contacts, w_dist, w_fc, w_align, w_surround, w_q1)
        (grad,) = torch.autograd.grad(total.sum(), x)
    return total.detach(), grad, {k: v.detach() for k, v in terms.items()}

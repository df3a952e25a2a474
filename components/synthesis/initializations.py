"""Initial hand poses and contact assignments for synthesis (DESIGN §5.1).

Every candidate starts with its palm facing the objects from above the table:

1. an approach direction u, uniform on the spherical cap of half-angle ``init_max_polar_deg`` about +z
   (cos theta ~ U[cos theta_max, 1], phi ~ U[0, 2 pi));
2. the palm centre c_palm (mean of the hand's palm contact candidates, in the palm frame) at
   centroid + (r_bound + d) u with d ~ U[init_distance_min_m, init_distance_max_m] and r_bound the radius of
   a sphere around the objects' centroid that holds them all;
3. the palm normal (-y of the palm frame) along -u, the fingers (+z) at a random roll psi ~ U[0, 2 pi)
   about u, then a random rotation exp([omega]x), omega ~ N(0, jitter^2 I), about the palm centre;
4. actuated joints q = q_open + f (q_u - q_open) with q_u uniform in the joint limits and f =
   ``init_joint_fraction`` (the official release draws the lower half of each range, which bends
   symmetric joints such as the abductions to one side), coupled J0 from J1;
   With ``init_mode='pair'`` (scenes of two or more objects) steps 1-3 are replaced by
   :func:`pair_palm_poses`: the palm faces down above the centroid with the fingers across (or along) the
   line joining the two objects farthest apart;
5. contacts: ``contacts_per_object`` distinct candidate indices per object, all distinct in the row and,
   with ``contact_distinct_fingers``, the contacts of one object on different fingers; none in
   ``contact_regions_excluded``.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from components.hand import HandModel
from components.synthesis.energy import GraspProblem
from components.synthesis.pose import pack

#: Region name of the palm's contact candidates (``HandModel.region_names``).
PALM_REGION = "palm"


def _uniform(n: int, generator: torch.Generator, like: Tensor, low: float = 0.0, high: float = 1.0) -> Tensor:
    u = torch.rand(n, generator=generator, dtype=like.dtype, device=generator.device).to(like.device)
    return low + (high - low) * u


def palm_centre_local(hand: HandModel) -> Tensor:
    """Mean of the palm region's contact candidates in the palm frame at the open pose (3,)."""
    eye = torch.eye(3, dtype=hand.dtype, device=hand.device).unsqueeze(0)
    zero = torch.zeros(1, 3, dtype=hand.dtype, device=hand.device)
    points = hand.contact_candidates(zero, eye, hand.open_pose().unsqueeze(0))[0]  # (K, 3)
    return points[hand.contact_region_of == hand.region_names.index(PALM_REGION)].mean(0)


def axis_angle_to_matrix(omega: Tensor) -> Tensor:
    """Rodrigues:  R = I + sin(t) [k]x + (1 - cos(t)) [k]x^2,  t = |omega|, k = omega / t.   (B, 3) -> (B, 3, 3)."""
    angle = omega.norm(dim=-1, keepdim=True).clamp_min(torch.finfo(omega.dtype).tiny)  # (B, 1)
    k = omega / angle
    zero = torch.zeros_like(k[:, 0])
    cross = torch.stack([zero, -k[:, 2], k[:, 1], k[:, 2], zero, -k[:, 0], -k[:, 1], k[:, 0], zero], -1).reshape(-1, 3, 3)
    eye = torch.eye(3, dtype=omega.dtype, device=omega.device).expand_as(cross)
    s, c = torch.sin(angle)[..., None], torch.cos(angle)[..., None]
    return eye + s * cross + (1.0 - c) * cross @ cross


def approach_directions(n: int, max_polar_rad: float, generator: torch.Generator, like: Tensor) -> Tensor:
    """Unit vectors uniform on the cap {u : angle(u, +z) <= max_polar} (uniform in cos theta).  -> (n, 3)."""
    cos_t = _uniform(n, generator, like, math.cos(max_polar_rad), 1.0)
    phi = _uniform(n, generator, like, 0.0, 2.0 * math.pi)
    sin_t = (1.0 - cos_t * cos_t).clamp_min(0.0).sqrt()
    return torch.stack([sin_t * torch.cos(phi), sin_t * torch.sin(phi), cos_t], dim=-1)


def palm_rotations(u: Tensor, roll: Tensor) -> Tensor:
    """Palm frames whose y axis is u (so the palm normal -y points along -u) and whose z axis (fingers) is at
    angle ``roll`` about u:  y = u, z = cos(roll) e1 + sin(roll) e2 (e1, e2 orthonormal, normal to u),
    x = y x z.   u (B, 3), roll (B,) -> R (B, 3, 3) with columns (x, y, z)."""
    helper = torch.zeros_like(u)
    helper[:, 0] = 1.0
    near_x = u[:, 0].abs() > 0.9
    helper[near_x] = torch.tensor([0.0, 1.0, 0.0], dtype=u.dtype, device=u.device)
    e1 = torch.nn.functional.normalize(torch.cross(u, helper, dim=-1), dim=-1)
    e2 = torch.cross(u, e1, dim=-1)
    z = torch.cos(roll)[:, None] * e1 + torch.sin(roll)[:, None] * e2
    x = torch.cross(u, z, dim=-1)
    return torch.stack([x, u, z], dim=-1)


def pair_palm_rotations(line: Tensor, sign: Tensor, roll_mode: str, generator: torch.Generator) -> Tensor:
    """Palm frames facing straight down (palm normal -y = -z_world, so y = +z_world) with the fingers (+z)
    horizontal: across the horizontal unit vector ``line`` (z = sign * (e_z x line)), along it
    (z = sign * line) or at a uniform roll (``roll_mode`` 'across' / 'along' / 'uniform').
    line (3,), sign (B,) of +-1 -> R (B, 3, 3) with columns (x, y, z), x = y x z."""
    batch = sign.shape[0]
    up = torch.zeros(batch, 3, dtype=line.dtype, device=line.device)
    up[:, 2] = 1.0
    if roll_mode == "uniform":
        return palm_rotations(up, _uniform(batch, generator, line, 0.0, 2.0 * math.pi))
    direction = line if roll_mode == "along" else torch.cross(up[0], line, dim=-1)
    z = sign[:, None] * direction.expand(batch, 3)
    x = torch.cross(up, z, dim=-1)
    return torch.stack([x, up, z], dim=-1)


def object_line(objects) -> Tensor:
    """Horizontal unit vector from one to the other of the two objects whose centres are farthest apart (3,)."""
    pos = objects.positions
    gaps = (pos[:, None, :2] - pos[None, :, :2]).norm(dim=-1)
    i, j = divmod(int(gaps.argmax()), pos.shape[0])
    d = torch.zeros(3, dtype=pos.dtype, device=pos.device)
    d[:2] = pos[j, :2] - pos[i, :2]
    return d / d.norm().clamp_min(1e-9)


def pair_palm_poses(problem: GraspProblem, generator: torch.Generator) -> tuple[Tensor, Tensor]:
    """``init_mode='pair'``: palm rotations (B, 3, 3) of :func:`pair_palm_rotations` (random sign, then the
    random jitter rotation of ``init_jitter_deg``) and palm centres (B, 3) above the objects' centroid at
    height U[init_pair_height_m] above the highest object point.  -> (p (B, 3), R (B, 3, 3))."""
    hand, objects, cfg = problem.hand, problem.objects, problem.cfg
    batch, like = cfg.batch_size, objects.positions
    sign = torch.where(_uniform(batch, generator, like) < 0.5, -1.0, 1.0).to(like.dtype)
    rot = pair_palm_rotations(object_line(objects), sign, cfg.init_pair_roll, generator)
    omega = torch.randn(batch, 3, generator=generator, dtype=like.dtype, device=generator.device).to(like.device)
    rot = axis_angle_to_matrix(omega * math.radians(cfg.init_jitter_deg)) @ rot
    top = max(float(objects.mesh_vertices(j)[:, 2].max()) for j in range(objects.n_objects))
    low, high = cfg.init_pair_height_m
    centre = objects.centroid.expand(batch, 3).clone()
    centre[:, 2] = top + _uniform(batch, generator, like, low, high)
    p = centre - rot @ palm_centre_local(hand)
    return p, rot


def initial_joint_angles(hand: HandModel, n: int, fraction: float, generator: torch.Generator) -> Tensor:
    """q = q_open + f (q_u - q_open) on the 18 actuated joints, q_u uniform in the limits; J0 coupled.  -> (n, 22)."""
    uniform = hand.actuated(hand.sample_joint_angles(n, generator))  # (n, 18)
    open_pose = hand.actuated(hand.open_pose())  # (18,)
    return hand.expand_actuated(open_pose + fraction * (uniform - open_pose))


def random_distinct_contacts(batch: int, n_objects: int, per_object: int, n_candidates: int,
                             generator: torch.Generator, device) -> Tensor:
    """Candidate indices, distinct within each row (a random permutation prefix per row).  -> (B, n_obj, C)."""
    keys = torch.rand(batch, n_candidates, generator=generator, device=generator.device)
    return keys.argsort(dim=1)[:, : n_objects * per_object].reshape(batch, n_objects, per_object).to(device)


def initial_poses(problem: GraspProblem, generator: torch.Generator) -> tuple[Tensor, Tensor]:
    """Initial flat poses x (B, 31) and contacts (B, n_obj, C) for ``cfg.batch_size`` candidates (module docstring)."""
    hand, objects, cfg = problem.hand, problem.objects, problem.cfg
    batch = cfg.batch_size
    like = objects.positions
    if cfg.init_mode == "pair" and objects.n_objects >= 2:
        p, rot = pair_palm_poses(problem, generator)
    else:
        u = approach_directions(batch, math.radians(cfg.init_max_polar_deg), generator, like)  # (B, 3)
        roll = _uniform(batch, generator, like, 0.0, 2.0 * math.pi)
        rot = palm_rotations(u, roll)  # (B, 3, 3)
        omega = torch.randn(batch, 3, generator=generator, dtype=like.dtype, device=generator.device).to(like.device)
        rot = axis_angle_to_matrix(omega * math.radians(cfg.init_jitter_deg)) @ rot
        distance = objects.bounding_radius + _uniform(batch, generator, like, cfg.init_distance_min_m,
                                                      cfg.init_distance_max_m)
        palm_centre_world = objects.centroid + distance[:, None] * u  # (B, 3)
        p = palm_centre_world - rot @ palm_centre_local(hand)  # (B, 3): the palm centre lands on palm_centre_world
    q = initial_joint_angles(hand, batch, cfg.init_joint_fraction, generator)
    contacts = random_distinct_contacts(batch, objects.n_objects, cfg.contacts_per_object, problem.n_candidates,
                                        generator, hand.device)
    if cfg.contact_distinct_fingers or cfg.contact_regions_excluded:
        # redraw every contact uniformly among the allowed candidates (on a free finger with contact_distinct_fingers)
        from components.synthesis.optimizer import switch_contacts

        redraw = cfg.model_copy(update={"contact_switch_mode": "per_contact", "contact_switch_probability": 1.0,
                                        "contact_switch_local_probability": 0.0,
                                        "contact_switch_guided_probability": 0.0})
        contacts = switch_contacts(contacts, hand.contact_region_of, redraw, generator,
                                   finger_of=problem.finger_of if cfg.contact_distinct_fingers else None,
                                   candidate_allowed=problem.candidate_allowed)
    return pack(p, rot, q), contacts

"""Grasp closure: squeeze the fingers into the objects they touch before the lift starts.

A synthesised pre-grasp puts the hand's contact links within millimetres of the object surfaces, with no force
between them.  Lifting straight from it (the paper's "w/o RL") drops the objects; so does closing every flexion
joint blindly, which sweeps light objects across the table.  The closure here is the "squeeze toward the
closest object surface" execution of GenDexGrasp, in the form DexGraspNet uses to test grasps in simulation:

1. every hand link within ``closure_radius_m`` of an object contributes its closest point x_k and the
   direction n_k from it into the object (PyBullet's closest points, so it needs no contact labels and works on
   generated poses and end-of-reach states alike);
2. joint targets q + dq with dq the damped least-squares step that moves every x_k by ``closure_depth_m`` along
   n_k:  dq = (J^T J + lambda I)^-1 J^T b,  J the (3K x 18) Jacobian of the points w.r.t. the actuated joints
   (autograd through the hand's FK), b the stacked d n_k;  the position-controlled joints then press with up to
   ``joint_max_force_nm``;
3. the targets move there over ``closure_steps`` environment steps and stay for ``closure_settle_steps``, while a
   PD wrench holds the palm where the pre-grasp put it (the arm that carries a real hand).

Measured on 100 bench Syn-Pl pre-grasps, one perturbed trial each, closure then a straight lift at 4 N (README
"Grasp closure"): 10 % lifted, against 0 % without the closure and 3 % for the blind flexion squeeze (both with
this physics: ``solver_iterations`` 150, ``joint_max_force_nm`` 2; with PyBullet's 50 iterations and 5 N m the
closure lifted 0-2 %).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pybullet as pb
import torch

from components.hand import HandModel

if TYPE_CHECKING:  # the world imports this module
    from components.execution.lift_sim import LiftWorld


def closest_points(world: "LiftWorld", radius: float) -> tuple[list[int], list[int], np.ndarray, np.ndarray]:
    """For every (hand link, object) pair closer than ``radius`` (m): the link's row in ``HandModel.link_names``,
    the object's index in ``world.objects``, the closest point on the link (world, (K, 3)) and the unit direction
    from it into the object (K, 3)."""
    c = world.client
    row_of = {index: row for row, index in enumerate(world.link_index)}
    rows, owners, points, directions = [], [], [], []
    for number, body in enumerate(world.objects):
        nearest: dict[int, tuple] = {}
        for cp in pb.getClosestPoints(world.body, body, radius, physicsClientId=c):
            link, distance = cp[3], cp[8]
            if link in row_of and (link not in nearest or distance < nearest[link][8]):
                nearest[link] = cp
        for link, cp in nearest.items():
            rows.append(row_of[link])
            points.append(cp[5])  # on the hand
            directions.append([-x for x in cp[7]])  # contactNormalOnB points from the object to the hand
            owners.append(number)
    return rows, owners, np.asarray(points, dtype=np.float64).reshape(-1, 3), np.asarray(directions, dtype=np.float64).reshape(-1, 3)


def opposed_links(directions: np.ndarray, owners: list[int], above: float) -> np.ndarray:
    """Mask (K,) of the near links to press with ``lift.closure_links: opposed``: per object, the links whose push
    direction has an opposing partner on the same object (-d_i . d_j > ``above``, the opposition of
    ``benchmarks.lift_failures``).  A link without one pushes its object off the others; an object with no opposed
    pair keeps all its links (there is no grip to protect)."""
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    owner = np.asarray(owners)
    keep = np.ones(len(d), dtype=bool)
    for obj in np.unique(owner):
        mine = np.flatnonzero(owner == obj)
        opposed = (-(d[mine] @ d[mine].T) > above).any(axis=1)
        if opposed.any():
            keep[mine] = opposed
    return keep


def closure_targets(hand: HandModel, p: np.ndarray, R: np.ndarray, q: np.ndarray, rows: list[int],
                    points: np.ndarray, directions: np.ndarray, depth: float, damping: float) -> np.ndarray:
    """Joint angles (22,) that move the hand points ``points`` (world, on links ``rows``, hand at (p, R, q)) by
    ``depth`` along ``directions``, to first order: the damped least-squares step over the 18 actuated joints
    (module docstring), coupled J0 included.  No points: q unchanged."""
    if not rows:
        return np.asarray(q, dtype=np.float64).copy()
    dtype = hand.dtype
    p_t = torch.as_tensor(np.asarray(p, dtype=np.float64), dtype=dtype).reshape(1, 3)
    R_t = torch.as_tensor(np.asarray(R, dtype=np.float64), dtype=dtype).reshape(1, 3, 3)
    q_t = torch.as_tensor(np.asarray(q, dtype=np.float64), dtype=dtype).reshape(1, -1)
    actuated = [hand.joint_names.index(n) for n in hand.actuated_joint_names]
    q18 = q_t[:, actuated].clone()
    link = torch.as_tensor(rows)
    with torch.no_grad():
        frames = hand.link_poses(p_t, R_t, q_t)[0, link]  # (K, 4, 4) world
        world_points = torch.cat([torch.as_tensor(points, dtype=dtype), torch.ones(len(rows), 1, dtype=dtype)], 1)
        local = (torch.linalg.inv(frames) @ world_points.unsqueeze(-1))  # (K, 4, 1) in each link's frame

    def moved(x18: torch.Tensor) -> torch.Tensor:
        posed = hand.link_poses(p_t, R_t, hand.expand_actuated(x18))[0, link]
        return (posed @ local)[:, :3, 0].reshape(-1)

    jac = torch.autograd.functional.jacobian(moved, q18, vectorize=True)[:, 0, :]  # (3K, 18)
    b = depth * torch.as_tensor(directions, dtype=dtype).reshape(-1)
    step = torch.linalg.solve(jac.T @ jac + damping * torch.eye(jac.shape[1], dtype=dtype), jac.T @ b)
    return hand.expand_actuated(q18 + step)[0].detach().cpu().numpy().astype(np.float64)

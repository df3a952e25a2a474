"""Tabletop scenes: random, non-overlapping, resting placements of objects (DESIGN §4 "Objects").

A :class:`Scene` is a tuple of :class:`Placement` s — each object's origin (its centre of
mass) in the world (z up, table top at z = 0, metres) and its orientation as an xyzw
quaternion, the convention of PyBullet and scipy.

Every PyBullet client here is ``DIRECT``, owned by the function that connects it, always
addressed by its id, and disconnected in ``finally``.
"""

from __future__ import annotations

import itertools
import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Optional

import numpy as np
import pybullet as pb
from scipy.spatial.transform import Rotation

from components.errors import MultigraspError
from components.objects.config import ScenesConfig
from components.objects.library import ObjectLibrary

log = logging.getLogger(__name__)

#: Where bodies wait (far below the table) before a placement is tried.
PARKING_Z_M = -10.0
#: ``many_placement: cluster``: at most this many slides of a new object toward its neighbour, and the gap error
#: (m) at which it stops (the placement's gap is random anyway; this only keeps it inside [min_gap, max_gap]).
CLUSTER_SLIDE_STEPS = 4
CLUSTER_SLIDE_TOLERANCE_M = 5e-4
#: ``many_placement: cluster``: candidate spots tried for each new object (the most central clear one is kept).
CLUSTER_CANDIDATES = 8


@dataclass(frozen=True)
class Placement:
    """One object on the table: ``position`` of its origin (m, world) and ``quat_xyzw``."""

    name: str
    position: tuple[float, float, float]
    quat_xyzw: tuple[float, float, float, float]

    def matrix(self) -> np.ndarray:
        """4x4 transform from the object frame to the world."""
        transform = np.eye(4)
        transform[:3, :3] = Rotation.from_quat(self.quat_xyzw).as_matrix()
        transform[:3, 3] = self.position
        return transform

    def to_dict(self) -> dict:
        """JSON-ready dict."""
        return {"name": self.name, "position": list(self.position), "quat_xyzw": list(self.quat_xyzw)}

    @classmethod
    def from_dict(cls, data: dict) -> "Placement":
        """Inverse of :meth:`to_dict`."""
        return cls(name=str(data["name"]), position=tuple(float(v) for v in data["position"]), quat_xyzw=tuple(float(v) for v in data["quat_xyzw"]))


@dataclass(frozen=True)
class Scene:
    """Objects placed on the table."""

    objects: tuple[Placement, ...]

    @property
    def names(self) -> tuple[str, ...]:
        """Object names, in placement order."""
        return tuple(p.name for p in self.objects)

    def to_dict(self) -> dict:
        """JSON-ready dict: ``{"objects": [placement, ...]}``."""
        return {"objects": [p.to_dict() for p in self.objects]}

    @classmethod
    def from_dict(cls, data: dict) -> "Scene":
        """Inverse of :meth:`to_dict`."""
        return cls(objects=tuple(Placement.from_dict(p) for p in data["objects"]))

    @classmethod
    def from_arrays(cls, names, positions, quats_xyzw) -> "Scene":
        """A scene from object names and their positions / xyzw quaternions, each (n, 3) / (n, 4) or flattened
        (the ``object_positions`` / ``object_quats_xyzw`` columns of the synthesis tables)."""
        names = [str(n) for n in names]
        pos = np.asarray(positions, dtype=float).reshape(len(names), 3)
        quat = np.asarray(quats_xyzw, dtype=float).reshape(len(names), 4)
        return cls(objects=tuple(Placement(n, tuple(map(float, x)), tuple(map(float, o)))
                                 for n, x, o in zip(names, pos, quat)))


@dataclass(frozen=True)
class SettleResult:
    """What happened when a scene was simulated at rest for ``settle_time_s``.

    ``displacements``: distance moved by each object's origin (m); ``settled``: the scene
    after settling (use it as the physically consistent initial state); ``stable``: every
    displacement < ``settle_tolerance_m``; ``rotations_rad``: rotation of each object (rad).
    """

    max_displacement_m: float
    displacements: tuple[float, ...]
    settled: Scene
    stable: bool
    rotations_rad: tuple[float, ...] = ()


# ----------------------------------------------------------------------------- sampling


def random_resting_placement(lib: ObjectLibrary, name: str, half_range: float, rng: np.random.Generator) -> Placement:
    """A resting pose drawn by its probability, a uniform yaw in [0, 2 pi), and xy uniform in ``[-r, r]^2``;
    z from the resting pose, so the object's lowest point touches z = 0."""
    poses = lib.get(name).stable_poses()
    probs = np.array([p for _, p in poses])
    rest, _ = poses[int(rng.choice(len(poses), p=probs / probs.sum()))]
    yaw = rng.uniform(0.0, 2 * np.pi)
    rotation = Rotation.from_euler("z", yaw).as_matrix() @ rest[:3, :3]
    x, y = rng.uniform(-half_range, half_range, size=2)
    quat = Rotation.from_matrix(rotation).as_quat()  # xyzw
    return Placement(name=name, position=(float(x), float(y), float(rest[2, 3])), quat_xyzw=tuple(float(q) for q in quat))


def _closest_distance(client: int, body_a: int, body_b: int, max_distance: float) -> float:
    """Closest distance between two bodies if below ``max_distance`` (negative = penetration), else +inf."""
    points = pb.getClosestPoints(body_a, body_b, max_distance, physicsClientId=client)
    return min((p[8] for p in points), default=float("inf"))


def _within_max_gap(client: int, bodies: Sequence[int], max_gap: Optional[float]) -> bool:
    """True when ``max_gap`` is None or the bodies form one cluster: linking every two bodies whose closest
    distance is at most ``max_gap`` (m) connects them all (for two bodies: they are within it; for more, no
    group of them stands apart from the rest, so that all fit in one hand together)."""
    if max_gap is None or len(bodies) < 2:
        return True
    reached, frontier = {bodies[0]}, [bodies[0]]
    while frontier:
        a = frontier.pop()
        for b in bodies:
            if b not in reached and _closest_distance(client, a, b, max_gap) <= max_gap:
                reached.add(b)
                frontier.append(b)
    return len(reached) == len(bodies)


def max_gap_for(n_objects: int, cfg: ScenesConfig) -> Optional[float]:
    """Largest gap to a neighbour: ``max_gap_m``, or ``max_gap_many_m`` (when set) above ``many_threshold`` objects."""
    if n_objects > cfg.many_threshold and cfg.max_gap_many_m is not None:
        return cfg.max_gap_many_m
    return cfg.max_gap_m


def xy_half_range(n_objects: int, cfg: ScenesConfig) -> float:
    """Placement half range: ``xy_half_range_m``, or ``xy_half_range_many_m`` above ``many_threshold`` objects."""
    return cfg.xy_half_range_many_m if n_objects > cfg.many_threshold else cfg.xy_half_range_m


def footprint_radius(lib: ObjectLibrary, placement: Placement) -> float:
    """Radius (m) of the smallest circle about the object's origin that holds its posed mesh seen from above."""
    rotation = Rotation.from_quat(placement.quat_xyzw).as_matrix()
    vertices = np.asarray(lib.get(placement.name).mesh.vertices) @ rotation.T
    return float(np.linalg.norm(vertices[:, :2], axis=1).max())


def _slide_next_to(lib: ObjectLibrary, anchor: Placement, anchor_body: int, pose: Placement, body: int, gap: float,
                   direction: float, client: int) -> Placement:
    """``pose`` moved (in xy) to direction ``direction`` (rad) from ``anchor``, ``gap`` (m) away from it: it starts where
    the footprint circles (:func:`footprint_radius`) are ``gap`` apart and slides toward the anchor by the surplus of
    PyBullet's closest distance over ``gap``, up to ``CLUSTER_SLIDE_STEPS`` times.  ``body`` is left at the result."""
    unit = np.array([np.cos(direction), np.sin(direction)])
    rho = footprint_radius(lib, anchor) + footprint_radius(lib, pose) + gap
    for _ in range(CLUSTER_SLIDE_STEPS):
        xy = np.asarray(anchor.position[:2]) + rho * unit
        pose = Placement(name=pose.name, position=(float(xy[0]), float(xy[1]), pose.position[2]), quat_xyzw=pose.quat_xyzw)
        pb.resetBasePositionAndOrientation(body, pose.position, pose.quat_xyzw, physicsClientId=client)
        surplus = _closest_distance(client, anchor_body, body, rho) - gap
        if not np.isfinite(surplus) or abs(surplus) < CLUSTER_SLIDE_TOLERANCE_M:
            break
        rho -= surplus
    return pose


def cluster_placements(lib: ObjectLibrary, names: Sequence[str], half_range: float, gap: float, min_gap: float,
                       rng: np.random.Generator, client: int, bodies: Sequence[int]) -> list[Placement]:
    """One try of ``many_placement: cluster``: resting poses and yaws as :func:`random_resting_placement`.  Object
    i > 0 gets ``CLUSTER_CANDIDATES`` candidate spots, each next to a random earlier object in a uniform direction at
    a gap ~ U(min_gap, gap) (:func:`_slide_next_to`); of those at least ``min_gap`` from every earlier object it
    takes the one nearest the earlier objects' centroid, so the cluster grows compact instead of into a chain (the
    last candidate when none is clear: the caller's overlap check then rejects the try).  Then the whole cluster
    is shifted so that its centroid is uniform in ±``half_range``.  ``bodies`` (one per name, in ``client``) are
    moved along; overlaps and the cluster rule are checked by the caller, as for uniform scenes."""
    placed: list[Placement] = []
    for i, name in enumerate(names):
        pose = random_resting_placement(lib, name, 0.0, rng)
        if placed:
            centroid = np.mean([pl.position[:2] for pl in placed], axis=0)
            best, best_distance = None, np.inf
            for _ in range(CLUSTER_CANDIDATES):
                j = int(rng.integers(len(placed)))
                spot = _slide_next_to(lib, placed[j], bodies[j], pose, bodies[i], rng.uniform(min_gap, gap),
                                      rng.uniform(0.0, 2 * np.pi), client)
                clear = all(_closest_distance(client, bodies[k], bodies[i], min_gap) >= min_gap for k in range(i))
                distance = float(np.linalg.norm(np.asarray(spot.position[:2]) - centroid))
                if clear and distance < best_distance:
                    best, best_distance = spot, distance
            pose = best if best is not None else spot
        # every placed body stands where its placement says: the next objects slide against it and check it
        pb.resetBasePositionAndOrientation(bodies[i], pose.position, pose.quat_xyzw, physicsClientId=client)
        placed.append(pose)
    shift = rng.uniform(-half_range, half_range, size=2) - np.mean([pl.position[:2] for pl in placed], axis=0)
    return [Placement(name=pl.name, position=(pl.position[0] + float(shift[0]), pl.position[1] + float(shift[1]),
                                              pl.position[2]), quat_xyzw=pl.quat_xyzw) for pl in placed]


def sample_scene(lib: ObjectLibrary, names: Sequence[str], rng: np.random.Generator, cfg: ScenesConfig) -> Scene:
    """A random scene of ``names``: each object in a random resting pose (by probability), random
    yaw, xy uniform in ±range (above ``many_threshold`` objects with ``many_placement: cluster``: grown as a
    cluster, :func:`cluster_placements`); whole scenes are rejected while any two objects are closer than
    ``min_gap_m`` (PyBullet closest distance between their collision shapes) or, with ``max_gap_m``
    (``max_gap_many_m`` above ``many_threshold`` objects), while the objects do not form one cluster of
    neighbours within that gap, at most ``max_tries`` times.
    """
    names = list(names)
    if not names:
        raise MultigraspError("sample_scene needs at least one object name; pass e.g. ['cube', 'sphere']")
    for name in names:
        lib.require(name, where="the scene")
    half, gap = xy_half_range(len(names), cfg), max_gap_for(len(names), cfg)
    cluster = len(names) > cfg.many_threshold and cfg.many_placement == "cluster"
    client = pb.connect(pb.DIRECT)
    try:
        bodies = [lib.get(n).pybullet_body(client, (0.0, 0.0, PARKING_Z_M * (i + 1)), (0.0, 0.0, 0.0, 1.0)) for i, n in enumerate(names)]
        for _ in range(cfg.max_tries):
            if cluster:
                placements = cluster_placements(lib, names, half, gap, cfg.min_gap_m, rng, client, bodies)
            else:
                placements = [random_resting_placement(lib, n, half, rng) for n in names]
            for body, placement in zip(bodies, placements):
                pb.resetBasePositionAndOrientation(body, placement.position, placement.quat_xyzw, physicsClientId=client)
            if all(_closest_distance(client, a, b, cfg.min_gap_m) >= cfg.min_gap_m for a, b in itertools.combinations(bodies, 2)) \
                    and _within_max_gap(client, bodies, gap):
                return Scene(objects=tuple(placements))
    finally:
        pb.disconnect(physicsClientId=client)
    key = "max_gap_many_m" if gap is not None and gap != cfg.max_gap_m else "max_gap_m"
    near = f" and within {gap * 100:.1f} cm of another (scenes.sampling.{key})" if gap else ""
    raise MultigraspError(
        f"could not place {names} on the table without overlap{near} in {cfg.max_tries} tries within "
        f"±{half * 100:.2f} cm; increase scenes.xy_half_range_m (xy_half_range_many_m above "
        f"{cfg.many_threshold} objects){' or max_gap_m' if near else ''} or scenes.max_tries, or use fewer / smaller objects"
    )


# ----------------------------------------------------------------------------- settling


def _rotation_angle(q_from: Sequence[float], q_to: Sequence[float]) -> float:
    """Angle (rad) of the rotation taking orientation ``q_from`` to ``q_to`` (xyzw)."""
    return float((Rotation.from_quat(q_to) * Rotation.from_quat(q_from).inv()).magnitude())


def settle_scene(lib: ObjectLibrary, scene: Scene, cfg: ScenesConfig) -> SettleResult:
    """Simulate ``scene`` on a table plane for ``settle_time_s`` at ``sim_hz`` in a private PyBullet
    DIRECT client and measure how far each object's origin moved; stable = all < ``settle_tolerance_m``."""
    client = pb.connect(pb.DIRECT)
    try:
        pb.setGravity(0.0, 0.0, -cfg.gravity_m_s2, physicsClientId=client)
        pb.setTimeStep(1.0 / cfg.sim_hz, physicsClientId=client)
        plane = pb.createCollisionShape(pb.GEOM_PLANE, physicsClientId=client)
        table = pb.createMultiBody(0.0, plane, physicsClientId=client)
        pb.changeDynamics(table, -1, lateralFriction=cfg.table_friction, restitution=0.0, physicsClientId=client)
        bodies = [lib.get(p.name).pybullet_body(client, p.position, p.quat_xyzw) for p in scene.objects]
        for _ in range(int(round(cfg.settle_time_s * cfg.sim_hz))):
            pb.stepSimulation(physicsClientId=client)
        final = [pb.getBasePositionAndOrientation(b, physicsClientId=client) for b in bodies]
    finally:
        pb.disconnect(physicsClientId=client)
    settled = Scene(objects=tuple(Placement(p.name, tuple(pos), tuple(quat)) for p, (pos, quat) in zip(scene.objects, final)))
    displacements = tuple(float(np.linalg.norm(np.subtract(pos, p.position))) for p, (pos, _) in zip(scene.objects, final))
    rotations = tuple(_rotation_angle(p.quat_xyzw, quat) for p, (_, quat) in zip(scene.objects, final))
    max_disp = max(displacements)
    return SettleResult(
        max_displacement_m=max_disp,
        displacements=displacements,
        settled=settled,
        stable=max_disp < cfg.settle_tolerance_m,
        rotations_rad=rotations,
    )


def sample_settled_scenes(
    lib: ObjectLibrary, names: Sequence[str], n: int, rng: np.random.Generator, cfg: ScenesConfig
) -> list[tuple[Scene, SettleResult]]:
    """``n`` sampled scenes of ``names`` that stay put when simulated (unstable ones are resampled,
    at most ``n * max_settle_attempts`` samples). Logs how many were sampled and rejected."""
    kept: list[tuple[Scene, SettleResult]] = []
    attempts = 0
    budget = n * cfg.max_settle_attempts
    while len(kept) < n and attempts < budget:
        scene = sample_scene(lib, names, rng, cfg)
        result = settle_scene(lib, scene, cfg)
        attempts += 1
        if result.stable:
            kept.append((scene, result))
    log.info("scenes of %s: %d stable of %d sampled (%d rejected as unstable)", list(names), len(kept), attempts, attempts - len(kept))
    if len(kept) < n:
        raise MultigraspError(
            f"only {len(kept)} of {n} scenes of {list(names)} stayed put within {cfg.settle_tolerance_m * 1000:.1f} mm "
            f"after {attempts} samples; raise scenes.settle_tolerance_m or scenes.max_settle_attempts, or check these objects' resting poses"
        )
    return kept

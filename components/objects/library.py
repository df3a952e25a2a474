"""The object library: :class:`ObjectModel` (one rigid object) and :class:`ObjectLibrary`.

An :class:`ObjectModel` is one rigid object in its own frame (origin at the centre of mass
of its mesh, metres), in the spirit of DexGraspNet's ``ObjectModel``: its mesh, a signed
distance function with normals for the grasp energy, surface samples for the networks,
resting poses for scene sampling, and its PyBullet body for simulation.

The library is read from ``assets/objects/library.yaml`` (or ``ObjectsConfig.library_file``)
plus ``ObjectsConfig.user`` meshes, and validated eagerly: any bad name or mesh is a
one-line :class:`MultigraspError` at construction.
"""

from __future__ import annotations

import hashlib
import json
import logging
from pathlib import Path
from typing import Literal

import numpy as np
import pybullet as pb
import pybullet_data
import torch
import trimesh
import yaml
from scipy.spatial.transform import Rotation
from pydantic import Field, ValidationError

from components.config_base import Section
from components.errors import MultigraspError
from components.objects import cache, meshes
from components.objects.config import ObjectsConfig
from components.objects.sdf import SDFGrid, grid_sdf, load_or_build_sdf_grid
from components.objects.shapes import AnyShape, MeshShape

log = logging.getLogger(__name__)

#: Bump when the way geometry is derived from a definition changes: every cache key changes.
GEOMETRY_VERSION = "objects-geometry-v1"
DEFAULT_LIBRARY_FILE = Path(__file__).resolve().parents[2] / "assets" / "objects" / "library.yaml"
PYBULLET_DATA_PREFIX = "pybullet_data:"
#: Standard gravity (m/s^2) for the resting-pose check (a physical constant, not a setting).
STANDARD_GRAVITY_M_S2 = 9.81
#: Free space between the copies of an object in the resting-pose check (m).
POSE_CHECK_GAP_M = 0.05
#: A suggested `scale:` for a too-large mesh brings its width to this fraction of the limit.
SCALE_SUGGESTION_FILL = 0.8
#: Oversampling factor of the random pool that farthest-point sampling thins to ``n`` points.
SURFACE_POOL_FACTOR = 4


class ObjectSpec(Section):
    """One entry of the library file: what the object is made of."""

    role: Literal["train", "ood", "many", "extra", "user"] = Field(..., description="Which split the object is meant for (documentation; the config's train/ood lists decide).")
    shape: AnyShape = Field(..., description="Primitive parameters or mesh source.")
    mass_kg: float | None = Field(None, gt=0, description="Mass; default from the config's density.")
    friction: float | None = Field(None, ge=0, description="Lateral friction; default from the config.")
    color: tuple[float, float, float, float] | None = Field(None, description="RGBA in [0, 1] for renders.")


class LibraryFile(Section):
    """Schema of ``assets/objects/library.yaml``."""

    version: Literal[1] = Field(..., description="File format version.")
    objects: dict[str, ObjectSpec] = Field(..., min_length=1, description="Objects by name.")


def resolve_source(source: str, base_dir: Path) -> Path:
    """``pybullet_data:<rel>`` -> the installed pybullet_data package; other relative paths -> ``base_dir``."""
    if source.startswith(PYBULLET_DATA_PREFIX):
        return Path(pybullet_data.getDataPath()) / source[len(PYBULLET_DATA_PREFIX) :]
    path = Path(source).expanduser()
    return path if path.is_absolute() else base_dir / path


def read_library_file(path: Path) -> LibraryFile:
    """Parse and validate the library YAML (one-line error naming the file and the first problem)."""
    try:
        raw = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise MultigraspError(f"cannot read the object library {path} ({exc.strerror}); fix objects.library_file") from None
    except yaml.YAMLError as exc:
        raise MultigraspError(f"object library {path} is not valid YAML ({str(exc).splitlines()[0]}); fix the file") from None
    try:
        return LibraryFile.model_validate(raw)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"])
        raise MultigraspError(f"object library {path}: {where}: {first['msg']}; fix the entry") from None


def _palette_color(name: str) -> tuple[float, float, float, float]:
    """A stable colour derived from the object's name (for objects without one): RGB in [0.3, 0.9], opaque."""
    h = int(hashlib.sha256(name.encode()).hexdigest()[:6], 16)
    return (0.3 + 0.6 * ((h >> 16) & 255) / 255, 0.3 + 0.6 * ((h >> 8) & 255) / 255, 0.3 + 0.6 * (h & 255) / 255, 1.0)


# ----------------------------------------------------------------------------- ObjectModel


class ObjectModel:
    """One rigid object in its own frame (origin at the centre of mass, metres).

    Attributes: ``name``, ``role``, ``mesh`` (trimesh, object frame, watertight),
    ``mass_kg``, ``friction``, ``color``, ``radius`` (max distance from the origin to the
    surface; later stages normalise torques by it), ``fingerprint`` (sha256 of the definition).

    Build through :class:`ObjectLibrary`, which validates the definition.
    """

    def __init__(
        self,
        name: str,
        spec: ObjectSpec,
        mesh: trimesh.Trimesh,
        source_transform: np.ndarray,
        base_dir: Path,
        mass_kg: float,
        friction: float,
        fingerprint: str,
        cfg: ObjectsConfig,
        cache_dir: Path,
    ):
        self.name = name
        self.role = spec.role
        self.spec = spec
        self.mesh = mesh
        self.mass_kg = float(mass_kg)
        self.friction = float(friction)
        self.color = spec.color or _palette_color(name)
        self.fingerprint = fingerprint
        self.radius = float(np.linalg.norm(mesh.vertices, axis=1).max())
        self._source_transform = source_transform  # (4, 4): scaled file coordinates -> object frame
        self._base_dir = base_dir
        self._cfg = cfg
        self._cache_dir = cache_dir
        self._grid: SDFGrid | None = None
        self._grid_tensors: dict[tuple[str, torch.dtype], tuple[torch.Tensor, torch.Tensor, torch.Tensor]] = {}
        self._stable: tuple[np.ndarray, np.ndarray] | None = None
        self._collision_file: Path | None = None
        self._collision_hull: trimesh.Trimesh | None = None

    def __repr__(self) -> str:
        ext = self.mesh.extents * 100
        return f"ObjectModel({self.name!r}, {ext[0]:.1f} x {ext[1]:.1f} x {ext[2]:.1f} cm, {self.mass_kg * 1000:.0f} g)"

    @property
    def is_analytic(self) -> bool:
        """True if the SDF is an analytic formula (primitives), False if a cached grid (meshes)."""
        return not isinstance(self.spec.shape, MeshShape)

    # ------------------------------------------------------------------ signed distance

    def sdf(self, points: torch.Tensor) -> torch.Tensor:
        """Signed distance (..., ) of ``points`` (..., 3) in the object frame; negative inside.

        Differentiable w.r.t. ``points``; runs on ``points.device`` in ``points.dtype``.
        Primitives: analytic (``sdf.py``). Meshes: trilinear interpolation of a cached grid
        (built on first use, see ``ObjectsConfig.sdf_grid_resolution``), extrapolated outside it.
        """
        if self.is_analytic:
            return self.spec.shape.sdf(points)
        values, lower, upper = self._grid_on(points.device, points.dtype)
        return grid_sdf(values, lower, upper, points)

    def sdf_and_normal(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Signed distance (...) and outward unit normal (..., 3) = normalised gradient of the SDF.

        If ``points`` requires grad, both outputs stay differentiable w.r.t. it (the gradient
        is taken with ``create_graph=True``); otherwise they are plain tensors.
        """
        track = points.requires_grad
        with torch.enable_grad():
            query = points if track else points.detach().requires_grad_(True)
            dist = self.sdf(query)
            (grad,) = torch.autograd.grad(dist.sum(), query, create_graph=track)
        normal = grad / grad.norm(dim=-1, keepdim=True).clamp_min(torch.finfo(grad.dtype).tiny ** 0.5)
        if not track:
            dist, normal = dist.detach(), normal.detach()
        return dist, normal

    def _grid_key(self) -> str:
        return f"{self.fingerprint}:grid:{self._cfg.sdf_grid_resolution}:{self._cfg.sdf_grid_padding_m!r}"

    def sdf_grid_path(self) -> Path:
        """Where this mesh object's SDF grid is cached (``<cache_dir>/sdf/<name>-<key hash>.npz``)."""
        return self._cache_dir / "sdf" / f"{self.name}-{hashlib.sha256(self._grid_key().encode()).hexdigest()[:16]}.npz"

    def sdf_grid(self) -> SDFGrid:
        """The cached SDF grid of a mesh object (built and written under the cache dir on first use)."""
        if self._grid is None:
            cfg = self._cfg
            self._grid = load_or_build_sdf_grid(self.mesh, self.sdf_grid_path(), self._grid_key(), cfg.sdf_grid_resolution, cfg.sdf_grid_padding_m)
        return self._grid

    def _grid_on(self, device: torch.device, dtype: torch.dtype) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        slot = (str(device), dtype)
        if slot not in self._grid_tensors:
            grid = self.sdf_grid()
            self._grid_tensors[slot] = tuple(torch.as_tensor(np.asarray(a), dtype=dtype, device=device) for a in (grid.values, grid.lower, grid.upper))
        return self._grid_tensors[slot]

    # ------------------------------------------------------------------ surface samples

    def sample_surface(self, n: int, seed: int) -> np.ndarray:
        """``n`` surface points (n, 3), evenly spread: farthest-point sampling of a random
        area-weighted pool of ``4 n`` points. Primitives' points are projected onto the exact
        surface (one Newton step ``p - d(p) grad d(p)``). Deterministic for a given seed."""
        if n <= 0:
            raise MultigraspError(f"sample_surface needs a positive number of points, got {n}; pass n >= 1")
        rng = np.random.default_rng(seed)
        pool, _ = trimesh.sample.sample_surface(self.mesh, SURFACE_POOL_FACTOR * n, seed=rng)
        points = farthest_point_sampling(np.asarray(pool), n, int(rng.integers(len(pool))))
        if self.is_analytic:
            p = torch.as_tensor(points, dtype=torch.float64)
            dist, normal = self.sdf_and_normal(p)
            points = (p - dist[:, None] * normal).numpy()
        return points

    # ------------------------------------------------------------------ resting poses

    def stable_poses(self) -> list[tuple[np.ndarray, float]]:
        """Resting poses on the table: ``[(T (4, 4), probability), ...]``, most probable first.

        ``T`` maps object-frame points to the world with the object resting on z = 0 (its
        lowest point at z = 0, origin above (0, 0)). From ``trimesh.poses.compute_stable_poses``
        (quasi-static drop of the convex hull), keeping the most probable ones
        (``stable_pose_mass`` of the probability, at most ``stable_pose_max_count``), then only
        those that survive a drop in PyBullet (:func:`verify_resting_poses`); probabilities
        renormalised. Computed on the hull of the *collision* geometry (:meth:`collision_hull`)
        so that PyBullet agrees: for a mesh whose collision is a convex decomposition, the
        visual mesh may sit up to ~1 mm off the table. Cached in memory and on disk.
        """
        if self._stable is None:
            key = f"{self.fingerprint}:stable:" + json.dumps(
                self._cfg.model_dump(include={"stable_pose_mass", "stable_pose_max_count", "stable_pose_drop_m", "stable_pose_check_s",
                                              "stable_pose_check_hz", "stable_pose_tolerance_m", "stable_pose_tolerance_deg",
                                              "collision_margin_m", "rolling_friction", "spinning_friction"}),
                sort_keys=True,
            )
            path = self._cache_dir / "stable_poses" / f"{self.name}-{hashlib.sha256(key.encode()).hexdigest()[:16]}.npz"
            arrays = cache.load_arrays(path, key)
            if arrays is None or set(arrays) != {"transforms", "probs"}:
                cfg = self._cfg
                transforms, probs = meshes.compute_stable_poses(self.collision_hull(), cfg.stable_pose_mass, cfg.stable_pose_max_count)
                kept = verify_resting_poses(self, transforms, cfg)
                if not kept.any():
                    raise MultigraspError(
                        f"object '{self.name}': none of its {len(probs)} resting poses stays put when dropped in PyBullet; "
                        "check the mesh (a thin or degenerate shape?) or use `repair: convex_hull`"
                    )
                transforms, probs = transforms[kept], probs[kept] / probs[kept].sum()
                cache.save_arrays(path, key, {"transforms": transforms, "probs": probs})
            else:
                transforms, probs = arrays["transforms"], arrays["probs"]
            self._stable = (transforms, probs)
        transforms, probs = self._stable
        return [(t.copy(), float(p)) for t, p in zip(transforms, probs)]

    def graspable_width(self) -> float:
        """Narrowest horizontal width of the object on the table, in its *widest* resting pose (m).

        For each resting pose: the minimum width of its shadow on the table (rotating calipers);
        the maximum over poses, so every placement the scene sampler can produce fits the hand.
        """
        hull = self.collision_hull().vertices
        return max(meshes.narrowest_horizontal_width(hull, t[:3, :3]) for t, _ in self.stable_poses())

    # ------------------------------------------------------------------ PyBullet

    def pybullet_body(self, client_id: int, position, quat_xyzw) -> int:
        """Create this object in PyBullet client ``client_id`` at ``position`` / ``quat_xyzw`` (object frame = base frame).

        Collision: PyBullet's native sphere / box / cylinder / capsule where they exist; convex
        shapes as a convex mesh (``GEOM_MESH`` from the vertices); non-convex ones as a compound
        of convex pieces (a shipped decomposition such as ``duck_vhacd.obj``, an exact sector
        split for the torus, else ``pybullet.vhacd`` computed once and cached), with collision
        margin ``ObjectsConfig.collision_margin_m`` (Bullet's default 1 mm margin would float
        the object 1 mm above the table; native shapes keep theirs, which lies inside). Inertia: the
        mesh's (uniform density, principal axes = object axes), scaled to ``mass_kg``.
        Returns the body id.
        """
        native = self.spec.shape.native_geometry()
        if native is not None:
            col = pb.createCollisionShape(native.geom, physicsClientId=client_id, **native.collision_kwargs)
            vis = pb.createVisualShape(native.geom, rgbaColor=self.color, physicsClientId=client_id, **native.visual_kwargs)
            margin = {}
        else:
            col = self._mesh_collision_shape(client_id)
            margin = {"collisionMargin": self._cfg.collision_margin_m}
            vis = pb.createVisualShape(
                pb.GEOM_MESH,
                vertices=self.mesh.vertices.tolist(),
                indices=self.mesh.faces.ravel().tolist(),
                rgbaColor=self.color,
                physicsClientId=client_id,
            )
        body = pb.createMultiBody(
            baseMass=self.mass_kg,
            baseCollisionShapeIndex=col,
            baseVisualShapeIndex=vis,
            basePosition=list(position),
            baseOrientation=list(quat_xyzw),
            physicsClientId=client_id,
        )
        pb.changeDynamics(
            body,
            -1,
            lateralFriction=self.friction,
            rollingFriction=self._cfg.rolling_friction,
            spinningFriction=self._cfg.spinning_friction,
            restitution=0.0,
            localInertiaDiagonal=meshes.principal_inertia(self.mesh, self.mass_kg).tolist(),
            physicsClientId=client_id,
            **margin,
        )
        return body

    def _mesh_collision_shape(self, client_id: int) -> int:
        if self._is_convex():
            hull = self.mesh.convex_hull
            return pb.createCollisionShape(pb.GEOM_MESH, vertices=hull.vertices.tolist(), physicsClientId=client_id)
        return pb.createCollisionShape(pb.GEOM_MESH, fileName=str(self.collision_parts_file()), physicsClientId=client_id)

    def _is_convex(self) -> bool:
        shape = self.spec.shape
        return bool(self.mesh.is_convex) if isinstance(shape, MeshShape) else shape.is_convex()

    def collision_hull(self) -> trimesh.Trimesh:
        """Convex hull of the collision geometry (of all its convex pieces), object frame."""
        if self._collision_hull is None:
            self._collision_hull = trimesh.convex.convex_hull(np.concatenate(self.convex_parts()))
        return self._collision_hull

    def convex_parts(self) -> list[np.ndarray]:
        """Convex pieces (object frame) used for collisions; one piece for convex objects."""
        if self._is_convex():
            return [self.mesh.convex_hull.vertices]
        return meshes.parts_from_obj(self.collision_parts_file().read_bytes())

    def collision_parts_file(self) -> Path:
        """OBJ file (one ``o`` group per convex piece, object frame) in the cache dir; built once."""
        if self._collision_file is not None:
            return self._collision_file
        cfg = self._cfg
        key = f"{self.fingerprint}:parts:{cfg.vhacd_resolution}:{cfg.vhacd_max_vertices_per_hull}"
        path = self._cache_dir / "collision" / f"{self.name}-{hashlib.sha256(key.encode()).hexdigest()[:16]}.obj"
        data = cache.load_file(path, key)
        if data is None or not meshes.parts_from_obj(data):
            shape = self.spec.shape
            if isinstance(shape, MeshShape) and shape.collision is not None:
                source = resolve_source(shape.collision, self._base_dir)
                parts = meshes.convex_parts_from_file(source, self._source_transform, shape.scale)
            elif isinstance(shape, MeshShape):
                log.info("object '%s': computing a convex decomposition with pybullet.vhacd (once; cached)", self.name)
                parts = meshes.vhacd_parts(self.mesh, cfg.vhacd_resolution, cfg.vhacd_max_vertices_per_hull)
            else:
                parts = shape.convex_parts(cfg)
            cache.save_file(path, key, meshes.parts_to_obj(parts))
        self._collision_file = path
        return path


def verify_resting_poses(model: ObjectModel, transforms: np.ndarray, cfg: ObjectsConfig) -> np.ndarray:
    """Which resting poses (n, 4, 4) survive a drop in PyBullet: mask (n,) of bool.

    One copy of the object per pose, spread on a grid over a plane (lateral friction 1, so
    the contact friction is the object's own: Bullet multiplies the two), dropped from
    ``stable_pose_drop_m`` and simulated ``stable_pose_check_s``; a pose is kept if the copy
    ends within ``stable_pose_tolerance_m`` of its resting position and
    ``stable_pose_tolerance_deg`` of its resting orientation.
    """
    spacing = 2.0 * model.radius + POSE_CHECK_GAP_M
    side = int(np.ceil(np.sqrt(len(transforms))))
    client = pb.connect(pb.DIRECT)
    try:
        pb.setGravity(0.0, 0.0, -STANDARD_GRAVITY_M_S2, physicsClientId=client)
        pb.setTimeStep(1.0 / cfg.stable_pose_check_hz, physicsClientId=client)
        table = pb.createMultiBody(0.0, pb.createCollisionShape(pb.GEOM_PLANE, physicsClientId=client), physicsClientId=client)
        pb.changeDynamics(table, -1, lateralFriction=1.0, restitution=0.0, physicsClientId=client)
        rest_positions, rest_quats, bodies = [], [], []
        for i, transform in enumerate(transforms):
            position = np.array([spacing * (i % side), spacing * (i // side), transform[2, 3]])
            quat = Rotation.from_matrix(transform[:3, :3]).as_quat()
            drop = position + np.array([0.0, 0.0, cfg.stable_pose_drop_m])
            bodies.append(model.pybullet_body(client, drop.tolist(), quat.tolist()))
            rest_positions.append(position)
            rest_quats.append(quat)
        for _ in range(int(round(cfg.stable_pose_check_s * cfg.stable_pose_check_hz))):
            pb.stepSimulation(physicsClientId=client)
        final = [pb.getBasePositionAndOrientation(b, physicsClientId=client) for b in bodies]
    finally:
        pb.disconnect(physicsClientId=client)
    kept = np.zeros(len(transforms), dtype=bool)
    for i, ((pos, quat), rest_pos, rest_quat) in enumerate(zip(final, rest_positions, rest_quats)):
        moved = np.linalg.norm(np.subtract(pos, rest_pos))
        turned = np.degrees((Rotation.from_quat(quat) * Rotation.from_quat(rest_quat).inv()).magnitude())
        kept[i] = moved < cfg.stable_pose_tolerance_m and turned < cfg.stable_pose_tolerance_deg
    return kept


def farthest_point_indices(points: np.ndarray, n: int, start: int) -> np.ndarray:
    """Indices of a greedy farthest-point subset of ``points`` (P, 3) of size min(n, P), from ``start``."""
    n = min(n, len(points))
    chosen = np.empty(n, dtype=np.int64)
    chosen[0] = start
    dist = np.linalg.norm(points - points[start], axis=1)  # (P,) distance to the chosen set
    for i in range(1, n):
        chosen[i] = int(dist.argmax())
        dist = np.minimum(dist, np.linalg.norm(points - points[chosen[i]], axis=1))
    return chosen


def farthest_point_sampling(points: np.ndarray, n: int, start: int) -> np.ndarray:
    """Greedy farthest-point subset of ``points`` (P, 3) of size ``n`` (n, 3), starting at index ``start``."""
    return points[farthest_point_indices(points, n, start)]


# ----------------------------------------------------------------------------- ObjectLibrary


class ObjectLibrary:
    """All objects known to a run: the library file's plus the user's meshes.

    ``ObjectLibrary(cfg, cache_dir)`` validates eagerly: unknown names in the config, missing
    or unreadable mesh files, open meshes, and objects too large for the hand are each a
    one-line :class:`MultigraspError`. Derived geometry (SDF grids, resting poses, convex
    decompositions) is cached under ``cache_dir`` keyed by :meth:`fingerprint`.
    """

    def __init__(self, cfg: ObjectsConfig, cache_dir: Path):
        self.cfg = cfg
        self.cache_dir = Path(cache_dir)
        library_path = Path(cfg.library_file) if cfg.library_file is not None else DEFAULT_LIBRARY_FILE
        library = read_library_file(library_path)
        self._specs: dict[str, tuple[ObjectSpec, Path]] = {name: (spec, library_path.parent) for name, spec in library.objects.items()}
        for user in cfg.user:
            if user.name in self._specs:
                raise MultigraspError(f"user object '{user.name}' has the name of a library object; give it another name in objects.user")
            shape = MeshShape(type="mesh", source=str(user.mesh), scale=user.scale, repair=user.repair,
                              max_faces=user.max_faces)
            spec = ObjectSpec(role="user", shape=shape, mass_kg=user.mass_kg, friction=user.friction)
            self._specs[user.name] = (spec, Path.cwd())
        self._check_names()
        self._models: dict[str, ObjectModel] = {}
        for name in self._used_names():
            self.get(name)

    # ------------------------------------------------------------------ names

    @property
    def names(self) -> list[str]:
        """Every object available by name (library file order, then user meshes)."""
        return list(self._specs)

    @property
    def train(self) -> list[str]:
        """The training objects (``ObjectsConfig.train``)."""
        return list(self.cfg.train)

    @property
    def ood(self) -> list[str]:
        """The out-of-domain objects (``ObjectsConfig.ood``)."""
        return list(self.cfg.ood)

    def __contains__(self, name: object) -> bool:
        return name in self._specs

    def _used_names(self) -> list[str]:
        used = [*self.cfg.train, *self.cfg.ood, self.cfg.many_object, *(u.name for u in self.cfg.user)]
        return list(dict.fromkeys(used))

    def _check_names(self) -> None:
        fields = {"train": self.cfg.train, "ood": self.cfg.ood, "many_object": [self.cfg.many_object]}
        if self.cfg.heldout_pairs is not None:
            fields["heldout_pairs"] = [n for pair in self.cfg.heldout_pairs for n in pair]
        for field, names in fields.items():
            for name in names:
                self.require(name, where=f"objects.{field}")

    def require(self, name: str, where: str = "the request") -> None:
        """Raise a one-line error if ``name`` is not a known object (listing the known ones)."""
        if name not in self._specs:
            raise MultigraspError(
                f"unknown object '{name}' in {where}; known objects: {', '.join(self._specs)} "
                "(add your own mesh under objects.user)"
            )

    # ------------------------------------------------------------------ models

    def get(self, name: str) -> ObjectModel:
        """The :class:`ObjectModel` called ``name`` (built and validated on first use)."""
        self.require(name)
        if name not in self._models:
            spec, base_dir = self._specs[name]
            self._models[name] = self._build(name, spec, base_dir)
        return self._models[name]

    def fingerprint(self, name: str) -> str:
        """sha256 of the object's definition: its parameters (or mesh file bytes + scale), mass,
        friction, and the config fields that shape its geometry — a cache key for anything derived."""
        self.require(name)
        spec, base_dir = self._specs[name]
        return self._fingerprint(name, spec, base_dir)

    def _fingerprint(self, name: str, spec: ObjectSpec, base_dir: Path) -> str:
        shape = spec.shape.model_dump(mode="json")
        if isinstance(spec.shape, MeshShape) and not shape.get("max_faces"):
            shape.pop("max_faces", None)  # never simplified: the fingerprint it had before the field existed
        if isinstance(spec.shape, MeshShape):
            for key in ("source", "collision"):
                if shape[key] is not None:
                    path = resolve_source(shape[key], base_dir)
                    shape[key] = cache.sha256_bytes(path.read_bytes()) if path.is_file() else f"missing:{path}"
        definition = {
            "version": GEOMETRY_VERSION,
            "shape": shape,
            "mass_kg": spec.mass_kg,
            "friction": spec.friction,
            "tessellation": [self.cfg.sphere_subdivisions, self.cfg.primitive_sections],
            "default_density": self.cfg.default_density_kg_m3 if spec.mass_kg is None else None,
            "default_friction": self.cfg.default_friction if spec.friction is None else None,
        }
        return hashlib.sha256(json.dumps(definition, sort_keys=True).encode()).hexdigest()

    def _load_mesh(self, name: str, shape: MeshShape, path: Path, fingerprint: str) -> trimesh.Trimesh:
        """The cleaned mesh of the file in file units, simplified to ``shape.max_faces`` where it has more
        (:func:`meshes.simplify_mesh`).  A simplified mesh is cached under ``cache_dir/meshes/<fingerprint>.npz``:
        every later library of the work dir (each shard builds one) reads it instead of decimating again, and the
        simplification is logged once."""
        cached = self.cache_dir / "meshes" / f"{fingerprint}.npz"
        if shape.max_faces:
            arrays = cache.load_arrays(cached, fingerprint)
            if arrays is not None:
                return trimesh.Trimesh(arrays["vertices"], arrays["faces"], process=False)
        raw = meshes.clean_mesh(meshes.load_mesh_file(path, name))
        simple = meshes.simplify_mesh(raw, name, path, shape.max_faces)
        if simple is not raw:
            cache.save_arrays(cached, fingerprint, {"vertices": np.asarray(simple.vertices),
                                                    "faces": np.asarray(simple.faces)})
        return simple

    def _build(self, name: str, spec: ObjectSpec, base_dir: Path) -> ObjectModel:
        shape = spec.shape
        fingerprint = self._fingerprint(name, spec, base_dir)
        if isinstance(shape, MeshShape):
            path = resolve_source(shape.source, base_dir)
            raw = self._load_mesh(name, shape, path, fingerprint)
            raw.apply_scale(shape.scale)
            mesh = meshes.make_watertight(raw, name, path, shape.repair)
            transform = meshes.object_frame_transform(mesh)
            mesh.apply_transform(transform)
        else:
            mesh = shape.build_mesh(self.cfg)
            transform = np.eye(4)
        mass = spec.mass_kg if spec.mass_kg is not None else self.cfg.default_density_kg_m3 * float(mesh.volume)
        friction = spec.friction if spec.friction is not None else self.cfg.default_friction
        model = ObjectModel(name, spec, mesh, transform, base_dir, mass, friction, fingerprint, self.cfg, self.cache_dir)
        width = model.graspable_width()
        limit = self.cfg.max_graspable_width_m
        if width > limit:
            scale_now = shape.scale if isinstance(shape, MeshShape) else 1.0
            suggestion = scale_now * SCALE_SUGGESTION_FILL * limit / width
            raise MultigraspError(
                f"object '{name}' is too large for the hand: {width * 100:.1f} cm across on its narrowest horizontal side when resting "
                f"(limit objects.max_graspable_width_m = {limit * 100:.1f} cm); set `scale: {suggestion:.3g}` (now {scale_now:g}) or check the file's units"
            )
        return model


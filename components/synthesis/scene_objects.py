"""The posed objects of one scene, batched for the grasp energy: SDFs and normals of world points.

A :class:`SceneObjects` holds the world pose (R_o, t_o) of every object of a
:class:`~components.objects.Scene` (object frame = centre of mass, as in
:mod:`components.objects.library`) and evaluates each :class:`~components.objects.ObjectModel`'s
signed distance at world points by moving them into its frame:  x_o = R_o^T (x - t_o).  Normals are
turned back into the world:  n = R_o n_o.  The table is the plane z = ``table_height`` (0 in every
scene of :mod:`components.objects.scenes`).
"""

from __future__ import annotations

import numpy as np
import torch
from scipy.spatial.transform import Rotation
from torch import Tensor

from components.errors import MultigraspError
from components.objects import ObjectLibrary, ObjectModel, Scene


class SceneObjects:
    """The objects of ``scene`` posed in the world, on ``device`` in ``dtype`` (see module docstring)."""

    def __init__(self, library: ObjectLibrary, scene: Scene, device="cpu", dtype=torch.float32,
                 table_height: float = 0.0):
        if not scene.objects:
            raise MultigraspError("a scene for grasp synthesis needs at least one object; sample it with sample_scene")
        self.device, self.dtype = torch.device(device), dtype
        self.scene = scene
        self.names: list[str] = list(scene.names)
        self.models: list[ObjectModel] = [library.get(n) for n in self.names]
        self.table_height = float(table_height)
        rot = np.stack([Rotation.from_quat(pl.quat_xyzw).as_matrix() for pl in scene.objects])  # (n_obj, 3, 3)
        pos = np.array([pl.position for pl in scene.objects], dtype=np.float64)  # (n_obj, 3)
        self.rotations = torch.as_tensor(rot, dtype=dtype, device=self.device)  # (n_obj, 3, 3) object -> world
        self.positions = torch.as_tensor(pos, dtype=dtype, device=self.device)  # (n_obj, 3) centres of mass
        self.radii = torch.tensor([m.radius for m in self.models], dtype=dtype, device=self.device)  # (n_obj,)
        self._surface_cache: dict[tuple[int, int], Tensor] = {}

    @property
    def n_objects(self) -> int:
        return len(self.models)

    @property
    def centroid(self) -> Tensor:
        """Mean of the object centres (3,)."""
        return self.positions.mean(0)

    @property
    def bounding_radius(self) -> float:
        """Radius of a sphere about :attr:`centroid` that contains every object (m)."""
        return float(((self.positions - self.centroid).norm(dim=-1) + self.radii).max())

    # ------------------------------------------------------------------ frames
    def to_object(self, j: int, points: Tensor) -> Tensor:
        """World points into object j's frame:  x_o = R_o^T (x - t_o).   (..., 3) -> (..., 3)."""
        return (points - self.positions[j]) @ self.rotations[j]

    def to_world(self, j: int, points: Tensor) -> Tensor:
        """Object-j-frame points into the world:  x = R_o x_o + t_o.   (..., 3) -> (..., 3)."""
        return points @ self.rotations[j].T + self.positions[j]

    # ------------------------------------------------------------------ one object
    def object_sdf(self, j: int, points: Tensor) -> Tensor:
        """Signed distance (m, negative inside) of world points to object j.   (..., 3) -> (...)."""
        return self.models[j].sdf(self.to_object(j, points))

    def object_sdf_and_normal(self, j: int, points: Tensor) -> tuple[Tensor, Tensor]:
        """Signed distance (...) and outward unit normal in the world (..., 3) of object j at world points.
        Differentiable (normals included) when ``points`` requires grad."""
        dist, normal = self.models[j].sdf_and_normal(self.to_object(j, points))
        return dist, normal @ self.rotations[j].T

    # ------------------------------------------------------------------ all objects
    def sdf(self, points: Tensor) -> Tensor:
        """Signed distance of world points to every object.   points (B, N, 3) -> (B, N, n_obj)."""
        return torch.stack([self.object_sdf(j, points) for j in range(self.n_objects)], dim=-1)

    def sdf_and_normal(self, points: Tensor) -> tuple[Tensor, Tensor]:
        """Signed distances (B, N, n_obj) and world outward normals (B, N, n_obj, 3) for every object."""
        pairs = [self.object_sdf_and_normal(j, points) for j in range(self.n_objects)]
        return torch.stack([d for d, _ in pairs], dim=-1), torch.stack([n for _, n in pairs], dim=-2)

    def normals(self, points: Tensor) -> Tensor:
        """World outward unit normals of every object at world points.   (B, N, 3) -> (B, N, n_obj, 3)."""
        return self.sdf_and_normal(points)[1]

    # ------------------------------------------------------------------ surfaces
    def surface_points(self, n: int, seed: int) -> Tensor:
        """``n`` evenly spread surface samples of every object, in the world (``ObjectModel.sample_surface``).
        -> (n_obj, n, 3); cached per (n, seed)."""
        key = (n, seed)
        if key not in self._surface_cache:
            local = [torch.as_tensor(m.sample_surface(n, seed), dtype=self.dtype, device=self.device) for m in self.models]
            self._surface_cache[key] = torch.stack([self.to_world(j, x) for j, x in enumerate(local)])
        return self._surface_cache[key]

    def mesh_vertices(self, j: int) -> Tensor:
        """Vertices of object j's mesh in the world (V, 3)."""
        verts = torch.as_tensor(np.asarray(self.models[j].mesh.vertices), dtype=self.dtype, device=self.device)
        return self.to_world(j, verts)

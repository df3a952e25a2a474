"""Shape definitions of the object library: analytic primitives and mesh files.

Each primitive knows its tessellated mesh (for surface sampling, stable poses, rendering),
its analytic SDF (``sdf.py``) and its PyBullet collision geometry. All are built centred
at their centre of mass — the object frame — so the frustum (whose centroid is below
mid-height) shifts its SDF by :meth:`FrustumShape.com_offset`.

These classes are also the schema of ``assets/objects/library.yaml`` (``shape:`` entries).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Annotated, Literal, Union

import numpy as np
import pybullet as pb
import torch
import trimesh
from pydantic import Field, model_validator

from components.config_base import Section
from components.objects import sdf as sdf_fns
from components.objects.config import ObjectsConfig

PositiveLength = Annotated[float, Field(gt=0)]


@dataclass(frozen=True)
class NativeGeometry:
    """A PyBullet built-in collision geometry (``GEOM_*`` with its parameters)."""

    geom: int  # pybullet.GEOM_SPHERE / GEOM_BOX / GEOM_CYLINDER / GEOM_CAPSULE
    collision_kwargs: dict = field(default_factory=dict)
    visual_kwargs: dict = field(default_factory=dict)


class BoxShape(Section):
    """Rectangular box centred at the origin (cube, bar)."""

    type: Literal["box"] = Field(..., description="Primitive type.")
    size_m: tuple[PositiveLength, PositiveLength, PositiveLength] = Field(..., description="Full edge lengths along x, y, z (m).")

    def build_mesh(self, cfg: ObjectsConfig) -> trimesh.Trimesh:
        """12-triangle box."""
        return trimesh.creation.box(extents=self.size_m)

    def sdf(self, points: torch.Tensor) -> torch.Tensor:
        """Exact box SDF (``sdf.box_sdf``)."""
        return sdf_fns.box_sdf(points, tuple(s / 2 for s in self.size_m))

    def native_geometry(self) -> NativeGeometry | None:
        """``GEOM_BOX`` with half extents."""
        half = [s / 2 for s in self.size_m]
        return NativeGeometry(pb.GEOM_BOX, {"halfExtents": half}, {"halfExtents": half})

    def is_convex(self) -> bool:
        """A box is convex."""
        return True


class SphereShape(Section):
    """Ball centred at the origin."""

    type: Literal["sphere"] = Field(..., description="Primitive type.")
    radius_m: PositiveLength = Field(..., description="Radius (m).")

    def build_mesh(self, cfg: ObjectsConfig) -> trimesh.Trimesh:
        """Icosphere with ``cfg.sphere_subdivisions`` subdivisions (vertices on the sphere)."""
        return trimesh.creation.icosphere(subdivisions=cfg.sphere_subdivisions, radius=self.radius_m)

    def sdf(self, points: torch.Tensor) -> torch.Tensor:
        """Exact sphere SDF."""
        return sdf_fns.sphere_sdf(points, self.radius_m)

    def native_geometry(self) -> NativeGeometry | None:
        """``GEOM_SPHERE``."""
        return NativeGeometry(pb.GEOM_SPHERE, {"radius": self.radius_m}, {"radius": self.radius_m})

    def is_convex(self) -> bool:
        """A ball is convex."""
        return True


class CylinderShape(Section):
    """Solid cylinder along z, centred at the origin."""

    type: Literal["cylinder"] = Field(..., description="Primitive type.")
    radius_m: PositiveLength = Field(..., description="Radius (m).")
    height_m: PositiveLength = Field(..., description="Height along z (m).")

    def build_mesh(self, cfg: ObjectsConfig) -> trimesh.Trimesh:
        """Prism with ``cfg.primitive_sections`` sides, vertices on the cylinder."""
        return trimesh.creation.cylinder(radius=self.radius_m, height=self.height_m, sections=cfg.primitive_sections)

    def sdf(self, points: torch.Tensor) -> torch.Tensor:
        """Exact cylinder SDF."""
        return sdf_fns.cylinder_sdf(points, self.radius_m, self.height_m / 2)

    def native_geometry(self) -> NativeGeometry | None:
        """``GEOM_CYLINDER`` (PyBullet names the height ``height`` for collision, ``length`` for visuals)."""
        return NativeGeometry(
            pb.GEOM_CYLINDER,
            {"radius": self.radius_m, "height": self.height_m},
            {"radius": self.radius_m, "length": self.height_m},
        )

    def is_convex(self) -> bool:
        """A cylinder is convex."""
        return True


class CapsuleShape(Section):
    """Capsule along z: a cylinder of length ``length_m`` capped by two half balls."""

    type: Literal["capsule"] = Field(..., description="Primitive type.")
    radius_m: PositiveLength = Field(..., description="Radius (m).")
    length_m: PositiveLength = Field(..., description="Length of the cylindrical part, between the two ball centres (m); total length = length + 2 radius.")

    def build_mesh(self, cfg: ObjectsConfig) -> trimesh.Trimesh:
        """Surface of revolution of the capsule's profile (two quarter circles of ``primitive_sections / 4``
        segments joined by a segment), ``primitive_sections`` around the axis. (trimesh.creation.capsule
        leaves holes at the poles for fine counts.)"""
        return capsule_mesh(self.radius_m, self.length_m, cfg.primitive_sections)

    def sdf(self, points: torch.Tensor) -> torch.Tensor:
        """Exact capsule SDF."""
        return sdf_fns.capsule_sdf(points, self.radius_m, self.length_m / 2)

    def native_geometry(self) -> NativeGeometry | None:
        """``GEOM_CAPSULE`` (``height``/``length`` = cylindrical part)."""
        return NativeGeometry(
            pb.GEOM_CAPSULE,
            {"radius": self.radius_m, "height": self.length_m},
            {"radius": self.radius_m, "length": self.length_m},
        )

    def is_convex(self) -> bool:
        """A capsule is convex."""
        return True


def revolve_profile(profile: np.ndarray, sections: int) -> trimesh.Trimesh:
    """Closed surface of revolution about z of a profile ``(r, z)`` (P, 2) whose first and last
    points lie on the axis (they become the poles). Built ring by ring, so it is watertight
    for any ``sections`` (trimesh's revolve/capsule merge vertices near the poles and open up
    for fine tessellations)."""
    rings = np.asarray(profile[1:-1], dtype=np.float64)  # (R, 2), r > 0
    theta = np.linspace(0.0, 2 * np.pi, sections, endpoint=False)
    ring_xyz = np.stack(
        [rings[:, :1] * np.cos(theta), rings[:, :1] * np.sin(theta), np.broadcast_to(rings[:, 1:], (len(rings), sections))], axis=-1
    ).reshape(-1, 3)  # (R * S, 3)
    bottom, top = np.array([[0.0, 0.0, profile[0][1]]]), np.array([[0.0, 0.0, profile[-1][1]]])
    vertices = np.concatenate([bottom, ring_xyz, top])
    k = np.arange(sections)
    k_next = (k + 1) % sections
    ring = lambda i, j: 1 + i * sections + j  # noqa: E731 - vertex index of ring i, angle j
    faces = [np.stack([np.zeros(sections, dtype=int), ring(0, k_next), ring(0, k)], axis=1)]
    for i in range(len(rings) - 1):
        faces.append(np.stack([ring(i, k), ring(i, k_next), ring(i + 1, k_next)], axis=1))
        faces.append(np.stack([ring(i, k), ring(i + 1, k_next), ring(i + 1, k)], axis=1))
    top_index = len(vertices) - 1
    faces.append(np.stack([np.full(sections, top_index), ring(len(rings) - 1, k), ring(len(rings) - 1, k_next)], axis=1))
    mesh = trimesh.Trimesh(vertices, np.concatenate(faces), process=False)
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def capsule_mesh(radius: float, length: float, sections: int) -> trimesh.Trimesh:
    """Watertight capsule along z: the profile is two quarter circles (``sections / 4`` segments each) joined by the side."""
    quarter = np.linspace(0.0, np.pi / 2, max(sections // 4, 2) + 1)
    bottom = np.stack([radius * np.sin(quarter), -length / 2 - radius * np.cos(quarter)], axis=1)  # pole -> equator
    top = np.stack([radius * np.cos(quarter), length / 2 + radius * np.sin(quarter)], axis=1)  # equator -> pole
    return revolve_profile(np.concatenate([bottom, top]), sections)


class EllipsoidShape(Section):
    """Ellipsoid with semi-axes along x, y, z, centred at the origin."""

    type: Literal["ellipsoid"] = Field(..., description="Primitive type.")
    semi_axes_m: tuple[PositiveLength, PositiveLength, PositiveLength] = Field(..., description="Semi-axes a, b, c along x, y, z (m).")

    def build_mesh(self, cfg: ObjectsConfig) -> trimesh.Trimesh:
        """Icosphere scaled per axis (vertices on the ellipsoid)."""
        mesh = trimesh.creation.icosphere(subdivisions=cfg.sphere_subdivisions, radius=1.0)
        mesh.apply_scale(self.semi_axes_m)
        return mesh

    def sdf(self, points: torch.Tensor) -> torch.Tensor:
        """Approximate ellipsoid SDF (exact zero set and surface normals; see ``sdf.ellipsoid_sdf``)."""
        return sdf_fns.ellipsoid_sdf(points, self.semi_axes_m)

    def native_geometry(self) -> NativeGeometry | None:
        """None: PyBullet has no ellipsoid; the convex hull of the mesh is used."""
        return None

    def is_convex(self) -> bool:
        """An ellipsoid is convex."""
        return True


class FrustumShape(Section):
    """Truncated cone along z (wide base down in its canonical pose), origin at its centroid."""

    type: Literal["frustum"] = Field(..., description="Primitive type.")
    radius_bottom_m: PositiveLength = Field(..., description="Radius of the base at the low end (m).")
    radius_top_m: float = Field(..., ge=0, description="Radius of the top (m); 0 gives a cone.")
    height_m: PositiveLength = Field(..., description="Height along z (m).")

    def com_offset(self) -> float:
        """Height of the centroid above mid-height: ``z_c = h (R^2 + 2Rr + 3r^2) / (4 (R^2 + Rr + r^2)) - h/2``."""
        big, small, h = self.radius_bottom_m, self.radius_top_m, self.height_m
        return h * (big**2 + 2 * big * small + 3 * small**2) / (4 * (big**2 + big * small + small**2)) - h / 2

    def build_mesh(self, cfg: ObjectsConfig) -> trimesh.Trimesh:
        """Surface of revolution of the trapezoid profile, shifted so the centroid is at the origin."""
        half = self.height_m / 2
        profile = np.array([[0.0, -half], [self.radius_bottom_m, -half], [self.radius_top_m, half], [0.0, half]])
        mesh = revolve_profile(profile, cfg.primitive_sections)
        mesh.apply_translation([0.0, 0.0, -self.com_offset()])
        return mesh

    def sdf(self, points: torch.Tensor) -> torch.Tensor:
        """Exact frustum SDF, evaluated in the mid-height frame ``p + (0, 0, z_c)``."""
        shifted = points + torch.tensor([0.0, 0.0, self.com_offset()], dtype=points.dtype, device=points.device)
        return sdf_fns.frustum_sdf(shifted, self.radius_bottom_m, self.radius_top_m, self.height_m / 2)

    def native_geometry(self) -> NativeGeometry | None:
        """None: the convex hull of the mesh is used."""
        return None

    def is_convex(self) -> bool:
        """A frustum is convex."""
        return True


class HexPrismShape(Section):
    """Regular hexagonal prism along z; flat sides at y = ±apothem."""

    type: Literal["hex_prism"] = Field(..., description="Primitive type.")
    apothem_m: PositiveLength = Field(..., description="Centre-to-side distance (m); flat-to-flat width = 2 apothem.")
    height_m: PositiveLength = Field(..., description="Height along z (m).")

    def build_mesh(self, cfg: ObjectsConfig) -> trimesh.Trimesh:
        """6-sided prism; trimesh puts a corner on +x, matching ``sdf.hexagonal_prism_sdf``."""
        circumradius = self.apothem_m * 2 / math.sqrt(3)
        return trimesh.creation.cylinder(radius=circumradius, height=self.height_m, sections=6)

    def sdf(self, points: torch.Tensor) -> torch.Tensor:
        """Exact hexagonal-prism SDF."""
        return sdf_fns.hexagonal_prism_sdf(points, self.apothem_m, self.height_m / 2)

    def native_geometry(self) -> NativeGeometry | None:
        """None: the convex hull of the mesh is used."""
        return None

    def is_convex(self) -> bool:
        """A hexagonal prism is convex."""
        return True


class TorusShape(Section):
    """Torus (ring) around z: non-convex, with a hole."""

    type: Literal["torus"] = Field(..., description="Primitive type.")
    major_radius_m: PositiveLength = Field(..., description="Distance from the centre to the tube's centre line (m).")
    minor_radius_m: PositiveLength = Field(..., description="Radius of the tube (m); must be < major radius.")

    @model_validator(mode="after")
    def _tube_fits(self) -> "TorusShape":
        if self.minor_radius_m >= self.major_radius_m:
            raise ValueError("torus minor_radius_m must be smaller than major_radius_m")
        return self

    def build_mesh(self, cfg: ObjectsConfig) -> trimesh.Trimesh:
        """Torus with ``cfg.primitive_sections`` segments around the ring and half as many around the tube."""
        return trimesh.creation.torus(
            major_radius=self.major_radius_m,
            minor_radius=self.minor_radius_m,
            major_sections=cfg.primitive_sections,
            minor_sections=max(cfg.primitive_sections // 2, 8),
        )

    def sdf(self, points: torch.Tensor) -> torch.Tensor:
        """Exact torus SDF."""
        return sdf_fns.torus_sdf(points, self.major_radius_m, self.minor_radius_m)

    def native_geometry(self) -> NativeGeometry | None:
        """None: a compound of convex pieces (:meth:`convex_parts`) is used."""
        return None

    def is_convex(self) -> bool:
        """A torus is not convex."""
        return False

    def convex_parts(self, cfg: ObjectsConfig) -> list[np.ndarray]:
        """Exact convex decomposition for collisions: the hulls of ``primitive_sections / 4`` angular sectors.

        Each sector's hull bulges into the hole by at most ``R_in (1 - cos(pi / n))``
        (0.3 mm for the library torus) — tighter and deterministic, unlike V-HACD.
        """
        n_sectors = max(cfg.primitive_sections // 4, 8)
        ring = np.linspace(0.0, 2 * np.pi, 4 * n_sectors + 1)  # (4 n + 1,) sector boundaries every 4 steps
        tube = np.linspace(0.0, 2 * np.pi, max(cfg.primitive_sections // 2, 8), endpoint=False)
        parts = []
        radial = self.major_radius_m + self.minor_radius_m * np.cos(tube)  # (T,)
        height = self.minor_radius_m * np.sin(tube)  # (T,)
        for s in range(n_sectors):
            theta = ring[4 * s : 4 * s + 5, None]  # (5, 1)
            x, y = radial * np.cos(theta), radial * np.sin(theta)  # (5, T)
            pts = np.stack([x, y, np.broadcast_to(height, x.shape)], axis=-1).reshape(-1, 3)
            parts.append(trimesh.convex.convex_hull(pts).vertices)
        return parts


class MeshShape(Section):
    """A triangle mesh file (OBJ / STL / PLY)."""

    type: Literal["mesh"] = Field(..., description="A mesh file.")
    source: str = Field(..., description="Mesh path: 'pybullet_data:<relative path>' for files shipped by pybullet, else a path relative to the library file (or absolute).")
    scale: float = Field(1.0, gt=0, description="Uniform factor from file units to metres.")
    collision: str | None = Field(None, description="Optional convex decomposition shipped with the mesh (e.g. pybullet_data:duck_vhacd.obj), same frame and units as `source`.")
    repair: Literal["fill_holes", "convex_hull"] = Field("fill_holes", description="Handling of a non-watertight mesh (see UserMesh.repair).")
    max_faces: int | None = Field(None, ge=0, description="Simplify a mesh with more triangles than this to this many on load (see UserMesh.max_faces); None or 0 = never.")

    def native_geometry(self) -> NativeGeometry | None:
        """None: meshes use their hull (convex) or a convex decomposition."""
        return None


PrimitiveShape = Union[BoxShape, SphereShape, CylinderShape, CapsuleShape, EllipsoidShape, FrustumShape, HexPrismShape, TorusShape]
AnyShape = Annotated[Union[PrimitiveShape, MeshShape], Field(discriminator="type")]

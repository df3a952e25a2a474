"""Config sections of the object library and of scene sampling (DESIGN §4 "Objects")."""

from __future__ import annotations

from pathlib import Path
from typing import Literal, Optional

from pydantic import Field, field_validator, model_validator

from components.config_base import Section

#: The paper's 8 training objects, as project-made primitives (names in assets/objects/library.yaml).
DEFAULT_TRAIN_OBJECTS = ["cube", "cylinder", "sphere", "capsule", "ellipsoid", "frustum", "bar", "hex_prism"]
#: 3 out-of-domain geometries: two non-convex meshes shipped by pybullet_data, and a torus (a hole).
DEFAULT_OOD_OBJECTS = ["duck", "bunny", "torus"]


#: What :meth:`ObjectsConfig.key_dump` holds in place of a file's location (keys count its contents instead).
FILE_BY_CONTENTS = "<contents: objects.files>"

#: UserMesh.max_faces by default
DEFAULT_USER_MESH_MAX_FACES = 10_000


class UserMesh(Section):
    """A mesh brought by the user (OBJ, STL or PLY), added to the library under ``name``."""

    name: str = Field(..., min_length=1, description="Name used to refer to the object (in train/ood lists, scenes).")
    mesh: Path = Field(..., description="Path of the mesh file (.obj, .stl or .ply); relative paths are read from the folder of the config file that names them (from the working directory in --set).")
    scale: float = Field(1.0, gt=0, description="Uniform factor applied to the file's coordinates to get metres (e.g. 0.001 for a file in millimetres).")
    mass_kg: float | None = Field(None, gt=0, description="Mass in kg; default: volume x objects.default_density_kg_m3.")
    friction: float | None = Field(None, ge=0, description="Lateral friction coefficient; default: objects.default_friction.")
    max_faces: int = Field(
        DEFAULT_USER_MESH_MAX_FACES, ge=0,
        description="A mesh with more triangles than this is simplified to this many on load (quadric decimation, "
        "trimesh.Trimesh.simplify_quadric_decimation), with a log line; 0 = never.  trimesh's resting poses are "
        "quadratic in the convex hull's facets: a sphere-like scan of 327,680 triangles was still in them after 12 min, "
        "one of 20,480 took 33 s, one of ~10,000 6 s (once per work dir: the poses are cached).  10,000 triangles on "
        "a 5 cm object are ~1 mm apart, below the PN metric's 3 mm samples.")
    repair: Literal["fill_holes", "convex_hull"] = Field(
        "fill_holes",
        description=(
            "What to do with a mesh that is not watertight: 'fill_holes' fills small holes "
            "(with a warning) and rejects the mesh if it stays open; 'convex_hull' replaces it "
            "by its convex hull (with a warning) — use it for open scans of convex-ish objects."
        ),
    )


class ObjectsConfig(Section):
    """Which objects exist, which are used for training / out-of-domain tests, and how their geometry is cached."""

    train: list[str] = Field(default_factory=lambda: list(DEFAULT_TRAIN_OBJECTS), min_length=1, description="Training objects (the paper's 8): their singles and pairs make the training combinations.")
    ood: list[str] = Field(default_factory=lambda: list(DEFAULT_OOD_OBJECTS), description="Out-of-domain objects for the -Geo split (their singles and pairs).")
    user: list[UserMesh] = Field(default_factory=list, description="Meshes brought by the user; each becomes a library object usable in train/ood.")
    library_file: Path | None = Field(None, description="YAML describing the object library (its mesh paths are relative to it); default: the project's assets/objects/library.yaml. A relative path is read from the folder of the config file that names it (from the working directory in --set).")
    heldout_pairs: list[tuple[str, str]] | None = Field(
        None,
        description="Training pairs held out as unseen combinations (-Com); default: consecutive pairs of `train`, cyclically (8 pairs covering all 8 objects).",
    )
    many_object: str = Field("small_cylinder", description="Object repeated in the 3-/4-/5-object experiments (the paper uses small cylinders).")
    many_counts: list[int] = Field(default_factory=lambda: [3, 4, 5], description="Numbers of objects in the many-object experiments.")
    sdf_grid_resolution: int = Field(64, ge=8, le=512, description="Voxels per axis of the cached mesh SDF grids (64: max error < 0.6 mm within 1 cm of the duck/bunny surface; build ~8-12 s per mesh on 2 cores).")
    sdf_grid_padding_m: float = Field(0.015, gt=0, description="Margin of the SDF grid around the mesh bounds (m); outside it the distance is extrapolated.")
    surface_points: int = Field(2048, ge=16, description="Default number of surface samples per object (point clouds for the networks).")
    max_graspable_width_m: float = Field(
        0.10, gt=0,
        description="Largest narrowest-horizontal-width (over the object's resting poses) the Shadow Hand can hold; wider objects are rejected. 0.10 m ~ the hand's thumb-to-fingers aperture.",
    )
    default_friction: float = Field(0.8, ge=0, description="Lateral friction of user meshes that do not set one.")
    default_density_kg_m3: float = Field(600.0, gt=0, description="Density used for the mass of user meshes that do not set one (600: wood / hollow plastic).")
    rolling_friction: float = Field(1e-4, ge=0, description="PyBullet rolling friction of every object (keeps spheres and lying cylinders from rolling forever).")
    spinning_friction: float = Field(1e-4, ge=0, description="PyBullet spinning (torsional) friction of every object.")
    sphere_subdivisions: int = Field(3, ge=1, le=5, description="Icosphere subdivisions for the sphere / ellipsoid meshes (3: 1280 faces, chord error < 0.04 mm at 2.5 cm).")
    primitive_sections: int = Field(64, ge=8, description="Segments around the axis of tessellated cylinders, capsules, frusta and tori.")
    stable_pose_mass: float = Field(
        0.98, gt=0, le=1,
        description="Keep the most probable resting poses that together hold this fraction of the probability (drops rare, barely-stable facets).",
    )
    stable_pose_max_count: int = Field(64, ge=1, description="At most this many resting poses per object (a sphere has one per facet; they are all alike).")
    stable_pose_drop_m: float = Field(0.005, ge=0, description="Verification: each resting pose is dropped from this height above the table in PyBullet.")
    stable_pose_check_s: float = Field(1.0, gt=0, description="Verification: simulated time after the drop.")
    stable_pose_check_hz: int = Field(240, ge=30, description="Verification: PyBullet physics rate (Hz).")
    stable_pose_tolerance_m: float = Field(0.001, gt=0, description="Verification: a pose is kept if the object ends within this distance of its resting position...")
    stable_pose_tolerance_deg: float = Field(3.0, gt=0, description="...and within this angle of its resting orientation.")
    collision_margin_m: float = Field(1e-4, ge=0, description="PyBullet collision margin of mesh-based collision shapes (convex hulls, decompositions); it inflates the shape, so keep it far below the settle tolerance.")
    vhacd_resolution: int = Field(100_000, ge=10_000, description="Voxel resolution of pybullet.vhacd for non-convex meshes without a shipped decomposition.")
    vhacd_max_vertices_per_hull: int = Field(64, ge=8, le=1024, description="Vertex limit of each convex piece of the decomposition.")

    def used_names(self) -> set[str]:
        """The objects the pipeline's stages use: ``train``, ``ood``, ``many_object`` and the held-out pairs' (every
        scene, synthesis, point cloud and specialist is of these).  A user mesh outside them serves ``generate``."""
        return {*self.train, *self.ood, self.many_object} | {n for pair in self.heldout_pairs or [] for n in pair}

    def used_only(self) -> "ObjectsConfig":
        """This section without the user meshes no split uses (:meth:`used_names`): what a stage's cache key reads,
        so a mesh added only to ``objects.user`` (for ``generate``) keeps every trained stage.  The same object
        when every user mesh is used, so such configs keep their keys."""
        used = self.used_names()
        if all(u.name in used for u in self.user):
            return self
        return self.model_copy(update={"user": [u for u in self.user if u.name in used]})

    def key_dump(self) -> dict:
        """This section as cache keys read it: :meth:`used_only`, each file (user mesh, custom library) named by
        :data:`FILE_BY_CONTENTS` instead of its path, so keys follow what the files hold (the flows hash their
        contents beside it) and not where they lie: a config and its meshes moved to another folder or machine keep
        their keys.  A config without such files dumps as ``model_dump(mode="json")``."""
        section = self.used_only().model_dump(mode="json")
        section["user"] = [{**u, "mesh": FILE_BY_CONTENTS} for u in section["user"]]
        if section.get("library_file") is not None:
            section["library_file"] = FILE_BY_CONTENTS
        return section

    @field_validator("many_counts")
    @classmethod
    def _counts_at_least_two(cls, counts: list[int]) -> list[int]:
        if any(c < 2 for c in counts):
            raise ValueError("many_counts must be >= 2 objects each")
        return counts

    @model_validator(mode="after")
    def _no_duplicate_names(self) -> "ObjectsConfig":
        for label, names in (("train", self.train), ("ood", self.ood)):
            dup = sorted({n for n in names if names.count(n) > 1})
            if dup:
                raise ValueError(f"objects.{label} lists {dup} more than once")
        both = sorted(set(self.train) & set(self.ood))
        if both:
            raise ValueError(f"objects {both} are in both train and ood; an object belongs to one split")
        for pair in self.heldout_pairs or []:
            if pair[0] == pair[1] or not set(pair) <= set(self.train):
                raise ValueError(f"heldout_pairs entry {list(pair)} must be two different objects of objects.train")
        user_names = [u.name for u in self.user]
        dup = sorted({n for n in user_names if user_names.count(n) > 1})
        if dup:
            raise ValueError(f"objects.user defines {dup} more than once")
        return self


class ScenesConfig(Section):
    """How object placements on the table (z = 0) are sampled and checked (DESIGN §4 "Objects")."""

    xy_half_range_m: float = Field(0.0375, gt=0, description="Object centres are uniform in [-r, r]^2 around the table origin (paper: ±3.75 cm).")
    xy_half_range_many_m: float = Field(0.075, gt=0, description="Same range for scenes with more than `many_threshold` objects (±7.5 cm).")
    many_threshold: int = Field(3, ge=1, description="Scenes with more objects than this use xy_half_range_many_m.")
    min_gap_m: float = Field(0.002, ge=0, description="Placements whose objects are closer than this (PyBullet closest distance, m) are rejected.")
    max_gap_m: Optional[float] = Field(
        None, gt=0,
        description="If set, placements are also rejected unless the objects form one cluster when every two within "
        "this of each other (PyBullet closest distance, m) are linked, so that the objects fit in one hand together.  None = off (DESIGN §4: uniform "
        "in the range).  Measured on the mini run's cube + cylinder scenes: 44-69 % of candidates accepted at 4.8-5.7 cm "
        "between centres, 14-19 % at 7.5-7.8 cm.")
    max_gap_many_m: Optional[float] = Field(
        None, gt=0,
        description="max_gap_m for scenes with more than `many_threshold` objects (None = max_gap_m).  The 'many' "
        "split's small cylinders held by group force closure (synthesis fc_mode 'group') must nearly touch: 1 cm "
        "gave 6/32 accepted four-cylinder grasps (README 'Synthesis settings'); no profile sets it yet.")
    many_placement: Literal["uniform", "cluster"] = Field(
        "uniform",
        description="How scenes with more than `many_threshold` objects are drawn.  uniform: every centre uniform in "
        "±xy_half_range_many_m (rejected until the gap rules hold).  cluster: grown one object at a time, each next to a "
        "random placed one at a gap drawn in [min_gap_m, max gap] between their footprint circles, and the cluster's "
        "centroid then moved to a uniform point in ±xy_half_range_many_m; the same gap checks follow.  Needs "
        "max_gap_many_m (or max_gap_m).  Five small cylinders within a 1 cm gap: uniform in ±3.5 cm never places them "
        "in 20,000 tries (README 'Synthesis settings').")
    max_tries: int = Field(2000, ge=1, description="Rejection-sampling tries for one scene before giving up with an error.")
    settle_time_s: float = Field(1.0, gt=0, description="Simulated time for which a placed scene must stay put.")
    settle_tolerance_m: float = Field(0.002, gt=0, description="A scene is stable if every object origin moves less than this while settling.")
    sim_hz: int = Field(240, ge=30, description="PyBullet physics rate while settling (Hz).")
    gravity_m_s2: float = Field(9.81, gt=0, description="Gravity magnitude (along -z).")
    table_friction: float = Field(0.8, ge=0, description="Lateral friction of the table plane.")
    max_settle_attempts: int = Field(10, ge=1, description="sample_settled_scenes: sampled scenes allowed per requested stable scene before giving up.")

    @model_validator(mode="after")
    def _cluster_needs_a_gap(self) -> "ScenesConfig":
        if self.many_placement == "cluster" and self.max_gap_many_m is None and self.max_gap_m is None:
            raise ValueError("many_placement=cluster needs a gap to grow the cluster with: set "
                             "scenes.sampling.max_gap_many_m (e.g. 0.01)")
        return self

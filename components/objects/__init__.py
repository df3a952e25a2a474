"""Objects on the table: library (primitives + meshes), SDFs, resting poses, scenes, splits.

DESIGN §4 "Objects". Public API::

    from components.objects import ObjectLibrary, ObjectsConfig, ScenesConfig, sample_scene
    lib = ObjectLibrary(ObjectsConfig(), cache_dir=Path("runs/cache/objects"))
    duck = lib.get("duck")
    d, n = duck.sdf_and_normal(points)          # (..., ), (..., 3), object frame, torch
    scene = sample_scene(lib, ["cube", "duck"], np.random.default_rng(0), ScenesConfig())
"""

from components.objects.config import (
    DEFAULT_OOD_OBJECTS,
    DEFAULT_TRAIN_OBJECTS,
    ObjectsConfig,
    ScenesConfig,
    UserMesh,
)
from components.objects.library import ObjectLibrary, ObjectModel, ObjectSpec, farthest_point_sampling
from components.objects.scenes import (
    Placement,
    Scene,
    SettleResult,
    random_resting_placement,
    sample_scene,
    sample_settled_scenes,
    settle_scene,
    xy_half_range,
)
from components.objects.sdf import (
    SDFGrid,
    box_sdf,
    capsule_sdf,
    cylinder_sdf,
    ellipsoid_sdf,
    frustum_sdf,
    grid_sdf,
    hexagonal_prism_sdf,
    mesh_signed_distance,
    sphere_sdf,
    torus_sdf,
    trilinear_interpolate,
)
from components.objects.splits import SPLIT_KEYS, combinations, heldout_pairs

__all__ = [
    "DEFAULT_OOD_OBJECTS",
    "DEFAULT_TRAIN_OBJECTS",
    "SPLIT_KEYS",
    "ObjectLibrary",
    "ObjectModel",
    "ObjectSpec",
    "ObjectsConfig",
    "Placement",
    "SDFGrid",
    "Scene",
    "ScenesConfig",
    "SettleResult",
    "UserMesh",
    "box_sdf",
    "capsule_sdf",
    "combinations",
    "cylinder_sdf",
    "ellipsoid_sdf",
    "farthest_point_sampling",
    "frustum_sdf",
    "grid_sdf",
    "heldout_pairs",
    "hexagonal_prism_sdf",
    "mesh_signed_distance",
    "random_resting_placement",
    "sample_scene",
    "sample_settled_scenes",
    "settle_scene",
    "sphere_sdf",
    "torus_sdf",
    "trilinear_interpolate",
    "xy_half_range",
]

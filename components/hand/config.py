"""Config section of the Shadow Hand model (:class:`HandConfig`).

Every tunable of ``components/hand`` lives here; the geometry, kinematics and URDF code
receive these values as arguments and hold no numbers of their own except the ones read
from the MJCF (the source of truth for dimensions, limits and couplings).
"""

from pathlib import Path
from typing import Optional

from pydantic import Field

from components.config_base import Section


class HandConfig(Section):
    """How the Shadow Hand is modelled: contact candidates, collision set, numerics, URDF."""

    contact_points_per_region: int = Field(
        8,
        ge=1,
        description="Contact candidate points generated on the palmar patch of each of the 17 contact "
        "regions (so the hand has 17 x this many candidates).",
    )
    include_forearm: bool = Field(
        True,
        description="Whether the wrist capsule and the forearm (bounding cylinder of its convex mesh) are "
        "part of the model: their links appear in link_names / the URDF and their geoms in the "
        "distances. Keep True wherever the hand can meet the table.",
    )
    assets_dir: Optional[Path] = Field(
        None,
        description="Folder holding contact_regions.yaml and keypoints.yaml; None = the project's "
        "assets/hand folder.",
    )
    distance_epsilon: float = Field(
        1e-18,
        gt=0.0,
        description="Smoothing of every Euclidean norm, |v| ~ sqrt(|v|^2 + eps) - sqrt(eps) (eps in m^2): exact "
        "at 0, finite gradients everywhere, at most sqrt(eps) = 1e-9 m below the true norm.",
    )
    parallel_epsilon: float = Field(
        1e-12,
        gt=0.0,
        description="Segment-segment distance: below this value of |d1|^2 |d2|^2 - (d1.d2)^2 (m^4) the "
        "two segments are treated as parallel (Ericson, Real-Time Collision Detection, 5.1.9).",
    )
    golden_section_iterations: int = Field(
        30,
        ge=1,
        description="Iterations of the golden-section search that finds the closest point of a capsule "
        "axis to a box or cylinder in self_penetration (the bracket shrinks by 0.618 each time; "
        "30 iterations leave 5e-7 of the segment length, < 0.1 um on this hand).",
    )
    self_collision_screen_samples: int = Field(
        5,
        ge=2,
        description="Points sampled evenly along each capsule axis to screen capsule-box and capsule-cylinder "
        "pairs before the golden-section search: the prism's SDF is 1-Lipschitz, so min over the samples "
        "minus half their spacing is a lower bound of the pair's distance, and pairs whose bound is positive "
        "cannot penetrate and are not searched. Every penetration term and depth is unchanged; more samples "
        "screen out more pairs at a higher cost per pair.",
    )
    compile_distance_kernels: bool = Field(
        False,
        description="Compile the nearest-primitive search of signed_distance with torch.compile (fused "
        "kernels, ~3-4x faster on CPU; costs ~15 s of compilation per new (B, N) shape, so worth it only "
        "for long loops with fixed shapes such as synthesis).",
    )
    urdf_joint_velocity_limit: float = Field(
        2.0,
        gt=0.0,
        description="Velocity limit (rad/s) written into every URDF revolute joint; the MJCF has none.",
    )
    urdf_robot_name: str = Field("shadow_hand", description="Name of the <robot> element of the exported URDF.")

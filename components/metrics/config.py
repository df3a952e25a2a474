"""Config section of the grasp metrics (:class:`MetricsConfig`, DESIGN §6)."""

from typing import Literal, Optional

from pydantic import Field

from components.config_base import Section


class MetricsConfig(Section):
    """How Q1, PN and Div are measured (definitions in the docstrings of q1.py, penetration.py, diversity.py)."""

    # ------------------------------------------------------------------ Q1
    contact_distance_m: float = Field(
        0.005, gt=0.0,
        description="Q1: a hand surface sample is a contact of an object when it is within this distance of the object or inside it (DESIGN §6: 5 mm).")
    friction_coefficient: float = Field(
        0.5, gt=0.0,
        description="Q1: Coulomb friction coefficient of the linearised friction cones. The paper does not state it; 0.5 is "
        "the usual analysis value (Dex-Net, GraspIt!), below the simulated 0.8 so that Q1 is conservative.")
    friction_cone_edges: int = Field(8, ge=3, description="Q1: edges of the polyhedral approximation of each friction cone.")
    q1_hand_point_spacing_m: float = Field(
        0.004, gt=0.0, description="Q1: spacing of the samples on the hand's collision geometry that are tested as contacts.")
    q1_max_contacts: int = Field(
        32, ge=1,
        description="Q1 with q1_solver='capped': at most this many contacts per object (farthest-point subset of the samples in "
        "contact), which bounds the 6-D convex hull to max_contacts x edges wrenches (and reads Q1 low: README 'Q1 "
        "depends on its constants').")
    q1_solver: Literal["capped", "exact"] = Field(
        "exact",
        description="Q1: 'capped' = the hull of the q1_max_contacts farthest-point contacts only (a lower bound of Q1). "
        "'exact' = Q1 of every contact, by constraint generation (q1.q1_constraint_generation): the hull of a subset, "
        "grown by the wrenches beyond its nearest facets until that facet supports every wrench.")
    q1_exact_start: int = Field(
        8, ge=1,
        description="Q1 'exact': contacts (farthest-point subset) whose cone edges start the constraint generation.  The "
        "value does not change Q1, only its cost: on 40 bench pair grasps 0.18 / 0.41 / 0.95 s per grasp from 8 / 16 / "
        "32 contacts (capped at 32: 0.27 s).")
    q1_exact_rounds: int = Field(
        50, ge=1,
        description="Q1 'exact': rounds of constraint generation before the hull of every wrench is taken instead.")
    q1_exact_facets: int = Field(
        16, ge=1,
        description="Q1 'exact': the nearest facets of the subset's hull whose most violating wrench joins the subset "
        "each round (more: fewer, larger rounds).")
    q1_contact_mode: Literal["dense", "per_link"] = Field(
        "dense",
        description="Q1: which hand samples within contact_distance_m are contacts. 'dense' (this project): all of them "
        "(at most q1_max_contacts, spread by farthest-point sampling). 'per_link': one per hand link, its sample "
        "nearest the object -- the convention of the DexGraspNet / UniDexGrasp evaluation code ('nms').")
    q1_torque_scale_per_m: Optional[float] = Field(
        None, gt=0.0,
        description="Q1: torques are (x - c) x f divided by the object's radius when None (this project: scale-free); "
        "a number lambda multiplies them by lambda (1/m) instead (the DexGraspNet / UniDexGrasp evaluation code: 10).")
    q1_rank_tolerance: float = Field(
        1e-9, gt=0.0,
        description="Q1: the wrenches are rank-deficient (Q1 = 0) when their smallest singular value is below this fraction of the largest.")

    # ------------------------------------------------------------------ PN
    pn_object_points: int = Field(
        4096, ge=16,
        description="PN: surface samples per object tested against the hand's exact signed distance and the other objects "
        "(4096 on a 5 cm sphere: ~1.4 mm apart, depth error < 0.05 mm against a finger).")
    pn_hand_point_spacing_m: float = Field(
        0.003, gt=0.0, description="PN: spacing of the samples on the hand's collision geometry tested against the object SDFs.")

    # ------------------------------------------------------------------ shared
    surface_seed: int = Field(0, ge=0, description="Seed of the object surface samples.")
    batch_chunk: int = Field(64, ge=1, description="Grasps evaluated together (bounds memory of the dense point tests).")

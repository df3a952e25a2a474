"""Multi-object grasp synthesis: the DFC energy, annealed MALA, Adam refinement and the filter (DESIGN §5.1).

DexGraspNet-style split: :mod:`~.energy` (one function per term, :func:`energy` returns the total and
every named term), :mod:`~.optimizer` (:class:`Annealer` with ``try_step`` / ``accept_step``, :func:`refine`),
:mod:`~.initializations`, :mod:`~.filtering`, :mod:`~.scene_objects` (batched SDFs of a posed scene),
:mod:`~.hand_surface` (samples on the hand's collision geometry), :mod:`~.pose` (p, rot6d, q) and
:mod:`~.synthesize` (the whole pipeline for one scene)::

    from components.synthesis import SynthesisConfig, synthesize
    result = synthesize(hand, library, scene, SynthesisConfig(batch_size=64), torch.Generator().manual_seed(0))
"""

from components.synthesis.config import SynthesisConfig
from components.synthesis.energy import (
    GraspProblem,
    contact_alignment_energy,
    contact_distance_energy,
    energy,
    energy_and_grad,
    force_closure_error,
    friction_tilted_forces,
    hand_points_in_objects,
    joint_limit_energy,
    object_points_in_hand,
    self_penetration_energy,
    table_penetration,
)
from components.synthesis.filtering import ACCEPTED, FILTER_REASONS, count_reasons, filter_checks, filter_grasps
from components.synthesis.hand_surface import HandSurface
from components.synthesis.initializations import initial_poses
from components.synthesis.optimizer import Annealer, refine, run_mala, step_size_at, switch_contacts, temperature_at
from components.synthesis.pose import matrix_to_rot6d, pack, rot6d_to_matrix, unpack
from components.synthesis.scene_objects import SceneObjects
from components.synthesis.synthesize import SynthesisResult, synthesize

__all__ = [
    "ACCEPTED",
    "FILTER_REASONS",
    "Annealer",
    "GraspProblem",
    "HandSurface",
    "SceneObjects",
    "SynthesisConfig",
    "SynthesisResult",
    "contact_alignment_energy",
    "contact_distance_energy",
    "count_reasons",
    "energy",
    "energy_and_grad",
    "filter_checks",
    "filter_grasps",
    "force_closure_error",
    "friction_tilted_forces",
    "hand_points_in_objects",
    "initial_poses",
    "joint_limit_energy",
    "matrix_to_rot6d",
    "object_points_in_hand",
    "pack",
    "refine",
    "rot6d_to_matrix",
    "run_mala",
    "self_penetration_energy",
    "step_size_at",
    "switch_contacts",
    "synthesize",
    "table_penetration",
    "temperature_at",
    "unpack",
]

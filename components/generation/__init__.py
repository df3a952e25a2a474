"""Multi-object grasp generation (DESIGN §5.2-5.3; paper §"Multi-object Grasp Generation" and §"Refinement").

Modules, in pipeline order: :mod:`~.config` (``GeneratorConfig``, ``IKConfig``, ``RefineConfig``),
:mod:`~.canonical` (palm alignment about z), :mod:`~.pointnet2` (PointNet++ object tokens),
:mod:`~.denoiser` (cross-attention eps-network), :mod:`~.diffusion` (DDPM schedule, q_sample, loss,
ancestral sampling, training loop), :mod:`~.representation` (keypoints | joints), :mod:`~.ik`
(keypoints -> (p, R, q)), :mod:`~.generator` (model wrapper, palm-aligned generation) and
:mod:`~.refine` (E_pen + contact pull with tau 2 mm -> 1 mm) and :mod:`~.filter` (the paper's protocol
filter of generated pre-grasps: penetration and contact ratio)::

    from components.generation import GeneratorConfig, GraspGenerator, IKConfig, generate_grasps
    model = GraspGenerator(GeneratorConfig())
    p, R, q = generate_grasps(model, hand, clouds, palm_yaw, IKConfig(), per_scene=8)
"""

from components.generation.canonical import AlignedFrame, palm_direction, rotation_z, yaw_of
from components.generation.config import (
    GeneratedFilterConfig,
    GeneratorConfig,
    GuidanceConfig,
    IKConfig,
    RefineConfig,
    SamplerConfig,
)
from components.generation.dataset import GraspDataset, object_cloud, posed_clouds, scene_pivot
from components.generation.denoiser import GraspDenoiser, ObjectContext, ObjectInputs, timestep_embedding
from components.generation.diffusion import (
    GuideFn,
    NoiseSchedule,
    Standardizer,
    ddim_sample,
    ddim_step,
    ddim_timesteps,
    denoise_from,
    diffusion_loss,
    linear_beta_schedule,
    p_sample,
    q_sample,
    sample,
    train_diffusion,
)
from components.generation.filter import contact_ratio, keep_generated
from components.generation.generator import GraspGenerator, generate_grasps, guidance_hook
from components.generation.guidance import KeypointSpheres, guidance_energy, guidance_step, make_guide
from components.generation.ik import IKResult, kabsch, keypoint_error, palm_keypoint_indices, solve_ik
from components.generation.pointnet2 import (
    PointNet2Encoder,
    SetAbstraction,
    ball_query,
    farthest_point_sampling,
    group,
)
from components.generation.refine import (
    RefineResult,
    contact_energy,
    penetration_energy,
    refine_grasps,
    refinement_energy,
    refinement_problem,
    tau_at,
)
from components.generation.representation import from_representation, representation_dim, to_representation
from components.generation.training import TrainResult, extendable_step, load_generator, train_generator

__all__ = [
    "AlignedFrame", "GeneratedFilterConfig", "contact_ratio", "keep_generated", "GeneratorConfig", "GuidanceConfig", "GuideFn", "KeypointSpheres", "guidance_energy",
    "guidance_hook", "guidance_step", "make_guide", "GraspDenoiser", "GraspGenerator", "IKConfig", "IKResult", "NoiseSchedule",
    "ObjectContext", "ObjectInputs", "PointNet2Encoder", "RefineConfig", "RefineResult", "SamplerConfig",
    "SetAbstraction", "ddim_sample", "ddim_step", "ddim_timesteps", "denoise_from",
    "Standardizer", "ball_query", "contact_energy", "diffusion_loss", "farthest_point_sampling",
    "from_representation", "generate_grasps", "group", "kabsch", "keypoint_error", "linear_beta_schedule",
    "p_sample", "palm_direction", "palm_keypoint_indices", "penetration_energy", "q_sample", "refine_grasps",
    "refinement_energy", "refinement_problem", "representation_dim", "rotation_z", "sample", "solve_ik",
    "tau_at", "timestep_embedding", "to_representation", "train_diffusion", "yaw_of",
    "GraspDataset", "TrainResult", "extendable_step", "load_generator", "object_cloud", "posed_clouds", "scene_pivot",
    "train_generator",
]

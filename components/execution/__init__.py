"""Grasp execution in PyBullet: tabletop worlds and renders, the lift environment and its observation,
point-cloud features (PointNet) -- paper §"Multi-object Grasp Execution"."""

from components.execution.lift_config import LiftEnvConfig
from components.execution.lift_env import LiftEnv
from components.execution.lift_sim import GraspRecord, LiftWorld
from components.execution.observations import observation_blocks, observation_dim

__all__ = ["GraspRecord", "LiftEnv", "LiftEnvConfig", "LiftWorld", "observation_blocks", "observation_dim"]

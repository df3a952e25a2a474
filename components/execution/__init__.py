"""Grasp execution in PyBullet: tabletop worlds and renders, the lift environment and its observation,
point-cloud features (PointNet) -- paper §"Multi-object Grasp Execution".

The names below load on first use (PEP 562): ``components.execution.lift_config`` is read by every
config load, and importing the environment (torchrl, tensordict) at that point would cost every command
several seconds.
"""

import importlib

_EXPORTS = {
    "GraspRecord": "components.execution.lift_sim",
    "LiftEnv": "components.execution.lift_env",
    "LiftEnvConfig": "components.execution.lift_config",
    "LiftWorld": "components.execution.lift_sim",
    "observation_blocks": "components.execution.observations",
    "observation_dim": "components.execution.observations",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'components.execution' has no attribute {name!r}")

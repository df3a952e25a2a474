"""The torch device a command asks for, checked before any work starts.

``--device cuda`` (or ``run.device: cuda``, which the paper profile sets) on a machine whose torch cannot reach a GPU
used to fail inside the first stage that touched CUDA, with torch's traceback and after the stages before it had
run.  :func:`require_device` turns that into one line that names the problem and the fix.
"""

from __future__ import annotations

import torch

from components.errors import MultigraspError


def cuda_problem() -> str | None:
    """Why CUDA cannot be used by this process, or None when it can."""
    if not torch.backends.cuda.is_built():
        return f"this torch ({torch.__version__}) is a CPU-only build"
    if not torch.cuda.is_available():
        return f"this torch ({torch.__version__}) sees no CUDA device (torch.cuda.is_available() is False)"
    return None


def require_device(name: str, source: str = "--device") -> torch.device:
    """``torch.device(name)`` if this process can use it; otherwise :class:`MultigraspError` naming ``source`` (the
    option or config key that asked for the device) and the fix."""
    if name == "cuda":
        problem = cuda_problem()
        if problem is not None:
            raise MultigraspError(
                f"{source} is cuda but {problem} — use --device cpu, or install a CUDA build of torch first "
                "(README 'On a GPU')")
    return torch.device(name)

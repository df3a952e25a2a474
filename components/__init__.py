"""Pure library code of multigrasp: torch / numpy / pybullet / trimesh only.

Nothing in this package imports prefect or mlflow; ``tasks/`` wraps it.
"""


def _import_pybullet_quietly() -> None:
    """Import PyBullet once, without the banner its C module prints to stderr on import ("pybullet build time: …").

    The banner went ahead of every command's output, one-line errors included.  Every ``import pybullet`` after
    this one is served from ``sys.modules``."""
    import ctypes
    import os
    import sys

    if "pybullet" in sys.modules:
        return
    try:
        sys.stderr.flush()
        saved, devnull = os.dup(2), os.open(os.devnull, os.O_WRONLY)
    except (OSError, ValueError, AttributeError):  # no usable fd 2: import as is
        import pybullet  # noqa: F401
        return
    try:
        os.dup2(devnull, 2)
        import pybullet  # noqa: F401

        ctypes.CDLL(None).fflush(None)  # in case C's buffer still holds it
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)


_import_pybullet_quietly()

"""Pure library code of multigrasp: torch / numpy / pybullet / trimesh only.

Nothing in this package imports prefect or mlflow; ``tasks/`` wraps it.
"""

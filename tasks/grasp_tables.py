"""Reading the synthesize stage's grasp tables for the stages that learn from them (``train-generator``,
``specialists``) and the evaluations.  Its own module, so editing it never touches the synthesis shards'
cache keys."""

from __future__ import annotations

from typing import Literal

from tasks.artifacts import Manifest

RecordsSource = Literal["accepted", "lowest_energy"]


def grasp_rows(synthesis: Manifest, source: RecordsSource, per_scene: int, splits: list[str], max_objects: int,
               min_objects: int = 1):
    """Rows of the synthesis tables, sorted by scene and candidate: with ``source='accepted'`` the accepted
    grasps; with ``'lowest_energy'`` the ``per_scene`` lowest-energy candidates of each scene whatever the
    filter said (the smoke profile's stand-in when its tiny synthesis accepts none: plumbing, never results;
    their ``accepted`` column is kept).  Only ``splits`` and scenes of ``min_objects`` to ``max_objects`` objects."""
    import pandas as pd

    frame = pd.read_parquet(synthesis.path("grasps"))
    if source == "lowest_energy":
        both = [f for f in (frame, pd.read_parquet(synthesis.path("rejected"))) if len(f)]
        frame = pd.concat(both, ignore_index=True) if both else frame
        if len(frame):
            frame = frame.sort_values(["scene_id", "energy"]).groupby("scene_id", sort=True).head(per_scene)
    if not len(frame):
        return frame
    counts = frame["object_names"].map(len)
    frame = frame[frame["split"].isin(splits) & (counts <= max_objects) & (counts >= min_objects)]
    return frame.sort_values(["scene_id", "row"])

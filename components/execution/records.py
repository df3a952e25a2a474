"""Grasp records on disk: the pre-grasps an execution policy starts from (JSON, one list per file).

    save_records(path, records);  records = load_records(path)

Each entry: ``scene`` (``Scene.to_dict``), ``p`` (3), ``R`` (3 x 3), ``q`` (22) and optional ``meta``
(e.g. the synthesis row's scene id and split).  Loading a missing or malformed file raises a one-line
:class:`MultigraspError` naming the file and the command that writes it.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from components.errors import MultigraspError
from components.execution.lift_sim import GraspRecord
from components.fileio import atomic_write_text
from components.objects import Scene


def record_to_dict(record: GraspRecord) -> dict:
    return {"scene": record.scene.to_dict(), "p": np.asarray(record.p, float).tolist(),
            "R": np.asarray(record.R, float).tolist(), "q": np.asarray(record.q, float).tolist(),
            "meta": dict(record.meta)}


def record_from_dict(data: dict) -> GraspRecord:
    return GraspRecord(scene=Scene.from_dict(data["scene"]), p=np.asarray(data["p"], float),
                       R=np.asarray(data["R"], float).reshape(3, 3), q=np.asarray(data["q"], float),
                       meta=dict(data.get("meta", {})))


def save_records(path: Path, records) -> Path:
    return atomic_write_text(Path(path), json.dumps([record_to_dict(r) for r in records]))


def load_records(path: Path) -> list[GraspRecord]:
    path = Path(path)
    if not path.is_file():
        raise MultigraspError(f"grasp records {path} not found; run the stage that writes them "
                              "(multigrasp run --until synthesize) or fix the path")
    try:
        return [record_from_dict(d) for d in json.loads(path.read_text())]
    except (ValueError, KeyError, TypeError) as exc:
        raise MultigraspError(f"grasp records {path} are malformed ({type(exc).__name__}: {exc}); delete the file "
                              "and rerun the stage that writes it") from None

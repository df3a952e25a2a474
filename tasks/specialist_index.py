"""The specialists stage's ``index.json``, read so that its paths follow the work dir.

The merge unit of the specialists stage writes, for every bin, the folder of the bin's unit and the paths of its
policy and records, as absolute paths of the machine and work dir that trained them.  A work dir moved or copied
since (``mv runs runs-old``, rsync from a cluster to a laptop) keeps the same unit folders under its own
``stages/specialists/``, so :func:`read_specialist_index` maps every such path to the same file under the folder
that the index is read from.  Kept apart from ``tasks/specialists.py`` on purpose: that file is part of the
specialists' code version, and this reader changes no trained policy.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from tasks.artifacts import Manifest

#: Entries of an index row that name files inside the bin's unit folder.
FILE_ENTRIES = ("policy", "records")


def rebase_entry(entry: dict[str, Any], stage_folder: Path) -> dict[str, Any]:
    """One index row with its unit folder under ``stage_folder`` and its files inside that folder."""
    recorded = Path(entry["folder"])
    folder = Path(stage_folder) / recorded.name
    row = dict(entry, folder=str(folder))
    for name in FILE_ENTRIES:
        if name in entry:
            path = Path(entry[name])
            inside = path.relative_to(recorded) if path.is_relative_to(recorded) else Path(path.name)
            row[name] = str(folder / inside)
    return row


def read_specialist_index(merge: Manifest) -> dict[str, dict[str, Any]]:
    """``index.json`` of a specialists merge unit (bin label -> row), every path under the stage folder it is in now."""
    index = json.loads(merge.path("index").read_text())
    stage_folder = Path(merge.folder).parent
    return {label: rebase_entry(entry, stage_folder) for label, entry in index.items()}

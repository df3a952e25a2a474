"""Reading a ``synthesize`` stage's grasps for the measurement tools (``benchmarks.q1_conventions``,
``benchmarks.refine_effect``): the table is found from ``--profile`` / ``--config`` / ``--set`` / ``--workdir``
like ``multigrasp evaluate``, or given as ``--grasps FILE``; its accepted rows are served one scene at a time
as posed objects and pose tensors."""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from components.errors import MultigraspError

#: At most this many accepted grasps are measured by default (Q1 costs up to ~0.5 s a grasp on one core).
DEFAULT_MAX_GRASPS = 64


def add_source_args(parser: argparse.ArgumentParser) -> None:
    """The options that say which grasps are read (module docstring)."""
    parser.add_argument("--grasps", type=Path, help="a synthesize stage's grasps.parquet (default: found from --profile ...)")
    parser.add_argument("--profile", default="mini", help="profile whose synthesize stage is read (default: mini)")
    parser.add_argument("--config", type=Path, help="YAML config file on top of the profile")
    parser.add_argument("--set", action="append", default=[], dest="sets", help="KEY=VALUE override, as for multigrasp run")
    parser.add_argument("--workdir", type=Path, help="workdir of the run (default: the profile's)")
    parser.add_argument("--split", default="Pl", help="split whose accepted grasps are read ('all' = every split)")
    parser.add_argument("--max-grasps", type=int, default=DEFAULT_MAX_GRASPS, help="read at most this many grasps")


def resolve_source(args: argparse.Namespace):
    """(pipeline config, grasps.parquet path) of the parsed :func:`add_source_args` options; one-line
    :class:`MultigraspError` when the stage output or the file is missing."""
    from flows.config import load_config
    from flows.pipeline import stage_output

    if args.max_grasps < 1:
        raise MultigraspError("--max-grasps must be at least 1")
    overrides = {"workdir": args.workdir} if args.workdir else {}
    cfg = load_config(args.profile, args.config, args.sets, **overrides)
    if args.grasps is None:
        manifest = stage_output(cfg, "synthesize")
        if manifest is None:
            raise MultigraspError("no synthesize stage output for this config — run `multigrasp run --until "
                                  "synthesize` first (same --profile / --config / --set / --workdir), or pass --grasps")
        return cfg, manifest.path("grasps")
    if not args.grasps.is_file():
        raise MultigraspError(f"--grasps {args.grasps} is not a file — pass a synthesize stage's grasps.parquet")
    return cfg, args.grasps


def read_accepted(grasps: Path, split: str | None, max_grasps: int):
    """The first ``max_grasps`` accepted grasps (of ``split`` unless None) of a synthesize ``grasps.parquet``,
    indexed 0 .. n-1."""
    import pyarrow.parquet as pq

    frame = pq.read_table(grasps).to_pandas()
    if "accepted" in frame:
        frame = frame[frame["accepted"]]
    if split is not None:
        frame = frame[frame["split"] == split]
    if frame.empty or "p" not in frame:
        raise MultigraspError(f"no accepted grasps{' of split ' + split if split else ''} in {grasps} — "
                              "run `multigrasp run --until synthesize` first, or choose another --split")
    return frame.iloc[:max_grasps].reset_index(drop=True)


def scene_batches(frame, hand, library) -> Iterator[tuple[np.ndarray, object, object, object, object]]:
    """Per scene of ``frame``: (row positions in ``frame``, ``SceneObjects``, p (B, 3), R (B, 3, 3), q (B, 22))."""
    import torch

    from components.objects import Scene
    from components.synthesis import SceneObjects

    for _, group in frame.groupby("scene_id", sort=False):
        first = group.iloc[0]
        scene = Scene.from_arrays(first["object_names"], first["object_positions"], first["object_quats_xyzw"])
        objects = SceneObjects(library, scene, hand.device, hand.dtype)
        p = torch.as_tensor(np.stack(group["p"].to_numpy()), dtype=hand.dtype)
        R = torch.as_tensor(np.stack(group["R"].to_numpy()), dtype=hand.dtype).reshape(-1, 3, 3)
        q = torch.as_tensor(np.stack(group["q"].to_numpy()), dtype=hand.dtype)
        yield frame.index.get_indexer(group.index), objects, p, R, q


def tool_main(argv: list[str] | None, prog: str, description: str, run: Callable[..., dict],
              report: Callable[[dict], None]) -> int:
    """The command line of a measurement tool: the source options and ``--json OUT``; ``run(grasps, cfg, split,
    max_grasps)`` -> JSON-able result, written to OUT and summarised by ``report``.  A bad input is one line on
    stderr and exit status 2."""
    parser = argparse.ArgumentParser(prog=prog, description=description)
    add_source_args(parser)
    parser.add_argument("--json", type=Path, required=True, help="write the result here")
    args = parser.parse_args(argv)

    def compute() -> dict:
        cfg, grasps = resolve_source(args)
        return run(grasps, cfg, None if args.split == "all" else args.split, args.max_grasps)

    return finish_tool(args.json, compute, report)


def row_report(line: Callable[[dict], str]) -> Callable[[dict], None]:
    """A ``report`` for :func:`finish_tool` that prints ``line(row)`` for each of ``result["rows"]``."""
    def report(result: dict) -> None:
        for row in result["rows"]:
            print(line(row))
    return report


class PoseProgress:
    """Progress of a tool that lifts ``total`` poses one after the other: ``done()`` after each pose prints
    ``label: k/total poses, elapsed Ns, ETA Ms`` on ``stream`` (stderr) for the first pose, then at most every
    ``every_s`` seconds, and for the last one.  ``clock``: the time source (tests pass their own)."""

    def __init__(self, label: str, total: int, every_s: float = 30.0, stream=None,
                 clock: Callable[[], float] = time.monotonic):
        self.label, self.total, self.every_s, self.clock = label, int(total), float(every_s), clock
        self.stream = sys.stderr if stream is None else stream
        self.start = self.last = clock()
        self.count = 0

    def done(self) -> None:
        self.count += 1
        now = self.clock()
        if self.count not in (1, self.total) and now - self.last < self.every_s:
            return
        self.last = now
        elapsed = now - self.start
        left = f", ETA {elapsed / self.count * (self.total - self.count):.0f}s" if self.count < self.total else ""
        print(f"{self.label}: {self.count}/{self.total} poses, elapsed {elapsed:.0f}s{left}", file=self.stream,
              flush=True)


def check_positive(args: argparse.Namespace, *names: str) -> int | None:
    """Exit status 2 after a one-line error when any of the options ``names`` (argparse dests) is below 1."""
    if any(getattr(args, name) < 1 for name in names):
        flags = " and ".join(f"--{name.replace('_', '-')}" for name in names)
        print(f"error: {flags} must be at least 1", file=sys.stderr)
        return 2
    return None


def finish_tool(out: Path, compute: Callable[[], dict], report: Callable[[dict], None]) -> int:
    """Run ``compute``; write its JSON-able result to ``out`` and summarise it with ``report`` (exit status 0),
    or print a :class:`MultigraspError` as one line on stderr (exit status 2)."""
    try:
        result = compute()
    except MultigraspError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    report(result)
    return 0

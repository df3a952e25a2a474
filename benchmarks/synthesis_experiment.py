"""One synthesis experiment on one seeded scene, with any optimiser setting: the tool behind the
measurements in ``configs/shared/multi_object.yaml`` and the README's "Synthesis settings" table.

    python -m benchmarks.synthesis_experiment --objects cube,cylinder --seed 0 \\
        --profile bench --set batch_size=32 --set mala_steps=800 --device cpu --threads 1 --json out.jsonl

The scene is :func:`components.objects.sample_scene` of ``--objects`` with ``numpy`` seed ``--seed`` and the
profile's ``scenes.sampling`` (with ``--scene-set KEY=VALUE`` overrides, e.g. ``max_gap_m=0.025``); the
optimiser is the profile's ``synthesis.optimizer`` with the ``--set KEY=VALUE`` overrides (keys of
``SynthesisConfig``; values as in ``multigrasp run --set``).  One JSON line is appended to ``--json``: the setting, seconds,
filter reasons, accept rate, quantiles of the largest contact distance / E_fc / penetration over all
candidates, and Q1 / PN / Div over (at most :data:`benchmarks.synthesis.QUALITY_MAX` of) the accepted
grasps.  Candidates are independent, so the rate of one large batch equals that of several small ones.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

QUANTILES = (0.1, 0.25, 0.5, 0.75, 0.9)


def _quantiles(values) -> list[float]:
    return [round(float(v), 4) for v in np.quantile(values.detach().cpu().numpy(), QUANTILES)]


def effective_optimizer(synthesis, n_objects: int, sets: list[str]):
    """The stage's optimiser for ``n_objects`` objects (``synthesis.optimizer_for``) with the fields named in
    ``sets`` (already applied to ``synthesis.optimizer``) taking their ``--set`` values over the per-count ones."""
    explicit = {item.split("=", 1)[0].strip() for item in sets}
    return synthesis.optimizer_for(n_objects).model_copy(
        update={key: getattr(synthesis.optimizer, key) for key in explicit})


def sibling_spread(result) -> dict:
    """Median mean-|dq| (deg) and palm distance (mm) between accepted rows of the same lineage (copies made by
    ``resample_at``) and between accepted rows of different lineages; None where there are no such pairs."""
    from benchmarks.synthesis_progress import joint_differences_deg, lineage_pairs, median_or_none

    accepted = result.accepted.nonzero().flatten()
    joint = joint_differences_deg(result.q[accepted].double().cpu().numpy())
    p = result.p[accepted].double().cpu().numpy()
    palm = np.linalg.norm(p[:, None, :] - p[None, :, :], axis=-1) * 1000.0
    masks = lineage_pairs(result.lineage[accepted].cpu().numpy())
    out = {}
    for name, mask in zip(("siblings", "others"), masks):
        out[f"{name}_joint_diff_deg_median"] = median_or_none(joint[mask], 3)
        out[f"{name}_palm_mm_median"] = median_or_none(palm[mask], 2)
    return out


def run_experiment(objects: list[str], seed: int, sets: list[str], profile: str = "bench", device: str = "cpu",
                   threads: int = 0, scene_sets: tuple[str, ...] = ()) -> dict:
    """Synthesise one scene with the profile's optimiser for that many objects (``optimizer_for``: the
    ``optimizer_by_object_count`` fields over ``optimizer``, as the stage does) plus the ``KEY=VALUE`` overrides
    ``sets`` (keys of ``SynthesisConfig``, validated by the pipeline's ``--set`` machinery; they win over the
    per-count fields); returns the JSON-able summary."""
    import torch

    from benchmarks.synthesis import accepted_quality
    from components.hand import HandConfig, HandModel
    from components.objects import ObjectLibrary, ObjectsConfig, sample_scene
    from components.synthesis import synthesize
    from flows.config import load_config

    if threads:
        torch.set_num_threads(threads)
    config = load_config(profile, sets=[f"synthesis.optimizer.{item}" for item in sets]
                         + [f"scenes.sampling.{item}" for item in scene_sets])
    cfg = effective_optimizer(config.synthesis, len(objects), sets)
    hand = HandModel(HandConfig(), device=device)
    with tempfile.TemporaryDirectory() as tmp:
        library = ObjectLibrary(ObjectsConfig(), cache_dir=Path(tmp))
        scene = sample_scene(library, objects, np.random.default_rng(seed), config.scenes.sampling)
        centres = np.array([pl.position for pl in scene.objects])
        start = time.perf_counter()
        result = synthesize(hand, library, scene, cfg, torch.Generator(device=device).manual_seed(seed))
        seconds = time.perf_counter() - start
        terms = result.terms
        summary = {"objects": objects, "seed": seed, "profile": profile, "set": list(sets),
                   "scene_set": list(scene_sets), "centre_distance_max_mm": round(float(
                       max((np.linalg.norm(a[:2] - b[:2]) for i, a in enumerate(centres) for b in centres[i + 1:]),
                           default=0.0)) * 1000.0, 1), "device": device,
                   "threads": torch.get_num_threads(), "batch": cfg.batch_size, "seconds": round(seconds, 2),
                   "reasons": result.reason_counts(), "accept_rate": round(result.accept_rate, 4),
                   "lineages_accepted": result.stats["lineages_accepted"],
                   "resampled_rows": result.stats["resampled_rows"],
                   **sibling_spread(result),
                   "contact_distance_max_mm": _quantiles(terms["contact_distance_max"] * 1000.0),
                   "fc_max": _quantiles(terms["fc_per_object"].amax(-1)),
                   "penetration_mm": _quantiles(terms["penetration_depth_max"] * 1000.0),
                   "quantiles": list(QUANTILES),
                   **accepted_quality(hand, library, scene, result, config.synthesis.metrics,
                                      group=cfg.fc_mode == "group")}
    return summary


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--objects", default="cube,cylinder", help="comma-separated object names (default cube,cylinder)")
    parser.add_argument("--seed", type=int, default=0, help="scene and optimiser seed")
    parser.add_argument("--profile", default="bench", help="profile whose synthesis.optimizer is the base setting")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="optimiser override (repeatable)")
    parser.add_argument("--scene-set", action="append", default=[], metavar="KEY=VALUE",
                        help="scene sampling override (repeatable), e.g. max_gap_m=0.025")
    parser.add_argument("--device", choices=["cpu", "cuda"], default="cpu")
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0 = torch default)")
    parser.add_argument("--json", type=Path, required=True, metavar="OUT", help="JSON-lines file to append to")
    args = parser.parse_args(argv)
    from components.errors import MultigraspError

    try:
        summary = run_experiment(args.objects.split(","), args.seed, args.set, args.profile, args.device, args.threads,
                                 tuple(args.scene_set))
    except MultigraspError as exc:  # unknown object or profile, bad --set key or value: one line
        print(f"error: {exc}", file=sys.stderr)
        return 2
    args.json.parent.mkdir(parents=True, exist_ok=True)
    with args.json.open("a") as f:
        f.write(json.dumps(summary) + "\n")
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())

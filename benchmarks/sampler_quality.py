"""Quality and time of generated pre-grasps under several sampler / refinement settings, same model.

    python -m benchmarks.sampler_quality --profile mini --workdir runs/mini --json OUT [--checkpoint generator.pt]
        [--variant NAME=KEY=VALUE,KEY=VALUE ...] [--split Pl]

Each variant is a set of overrides of the ``generator`` stage (``sampler.*``, ``refine.*``, ``ik.*``); every
variant generates for the same scenes, palm directions and seeds (``evaluate pregrasp --source generated``'s
loop, :func:`flows.evaluate_generated.generated_rows`), so the rows differ only by the setting.  Per variant:
mean Q1, PN (mm) after refinement and Div (deg) over the grasps the paper's protocol keeps (``generator.eval_filter``;
``accept_rate`` kept / generated; ``q1_all`` / ``pn_mm_all`` over every grasp), the raw samples' mean penetration before refinement
(``pn_before_refine_mm``) and the wall time scaled to 256 grasps.  The model is the config's
``train-generator`` stage, or ``--checkpoint`` (e.g. one trained under an older code version).
Default variants: the paper's setting (100 ancestral DDPM steps, 200 refinement steps) and strided DDIM
with fewer denoiser calls and refinement steps.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from benchmarks.grasp_tables import finish_tool, row_report
from components.errors import MultigraspError

DEFAULT_VARIANTS = {
    "ddpm100+refine200 (paper)": [],
    "ddim50+refine200": ["sampler.method=ddim", "sampler.steps=50"],
    "ddim25+refine200": ["sampler.method=ddim", "sampler.steps=25"],
    "ddim25+refine50": ["sampler.method=ddim", "sampler.steps=25", "refine.steps=50"],
    "ddim10+refine50": ["sampler.method=ddim", "sampler.steps=10", "refine.steps=50"],
}


def parse_variant(text: str) -> tuple[str, list[str]]:
    """``NAME=KEY=VALUE,KEY=VALUE`` -> (NAME, [KEY=VALUE, ...]); ``NAME=`` is the config as it is."""
    name, sep, rest = text.partition("=")
    if not sep or not name:
        raise MultigraspError(f"--variant {text!r}: write NAME=KEY=VALUE,KEY=VALUE (e.g. ddim25=sampler.method=ddim,"
                              "sampler.steps=25) or NAME= for the config unchanged")
    return name, [item for item in rest.split(",") if item]


def run(cfg, variants: dict[str, list[str]], split: str, checkpoint: Path | None) -> dict:
    from flows.config import parse_set, with_overrides
    from flows.evaluate_generated import generated_rows

    rows, source = [], {}
    for name, sets in variants.items():
        overrides = {}
        for item in sets:
            keys, value = parse_set(f"generator.{item}")
            overrides[".".join(keys)] = value
        variant = with_overrides(cfg, overrides)
        measured, source = generated_rows(variant, settings=((f"Gen-{split}", split),), checkpoint=checkpoint)
        row = measured[0]
        rows.append({"variant": name, "overrides": sets, "q1": row["q1"], "pn_mm": row["pn_mm"],
                     "div_deg": row["div_deg"], "pn_before_refine_mm": row["pn_before_refine_mm"], "n": row["n"],
                     "n_generated": row["n_generated"], "accept_rate": row["accept_rate"], "q1_all": row["q1_all"], "pn_mm_all": row["pn_mm_all"],
                     "div_deg_all": row["div_deg_all"], "contact_ratio": row["contact_ratio"],
                     "time_s": row["time_s"], "time_256_s": row["time_256_s"]})
        print(f"sampler quality: {name}: kept {row['n']}/{row['n_generated']} Q1 {row['q1']} PN {row['pn_mm']} "
              f"Div {row['div_deg']} (all generated: Q1 {row['q1_all']} PN {row['pn_mm_all']}) PN before refinement "
              f"{row['pn_before_refine_mm']} time/256 {row['time_256_s']} s", file=sys.stderr, flush=True)
    return {"profile": cfg.profile, "split": split, "scenes": cfg.generator.eval_scenes,
            "grasps_per_scene": cfg.generator.eval_grasps_per_scene, **source, "rows": rows}


def main(argv: list[str] | None = None) -> int:
    from flows.config import load_config

    parser = argparse.ArgumentParser(prog="python -m benchmarks.sampler_quality", description=__doc__.split("\n\n")[0])
    parser.add_argument("--profile", default="mini")
    parser.add_argument("--config", type=Path)
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--workdir", type=Path)
    parser.add_argument("--checkpoint", type=Path, help="a generator.pt to use instead of the train-generator stage's")
    parser.add_argument("--variant", action="append", default=[], metavar="NAME=KEY=VALUE,...",
                        help="a setting to measure (repeatable); default: the DEFAULT_VARIANTS of the module")
    parser.add_argument("--split", default="Pl", help="scene split (default Pl)")
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0 = torch default)")
    parser.add_argument("--json", type=Path, required=True, help="write the result here")
    args = parser.parse_args(argv)

    def compute() -> dict:
        if args.checkpoint is not None and not args.checkpoint.is_file():
            raise MultigraspError(f"--checkpoint {args.checkpoint}: no such file — give a generator.pt "
                                  "(stages/train-generator/<key>/generator.pt)")
        variants = dict(parse_variant(v) for v in args.variant) if args.variant else DEFAULT_VARIANTS
        if args.threads:
            import torch

            torch.set_num_threads(args.threads)
        cfg = load_config(args.profile, args.config, args.sets, workdir=args.workdir)
        return run(cfg, variants, args.split, args.checkpoint)

    return finish_tool(args.json, compute, row_report(
        lambda row: f"{row['variant']:28s} Q1 {row['q1']}  PN {row['pn_mm']} mm  Div {row['div_deg']}  "
                    f"PN before refinement {row['pn_before_refine_mm']} mm  {row['time_256_s']} s / 256"))


if __name__ == "__main__":
    sys.exit(main())

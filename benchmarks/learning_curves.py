"""The specialists' learning curves in one figure, with a summary of each bin's trend.

    python -m benchmarks.learning_curves DIR [DIR ...] --out curves.png [--json OUT] [--smooth 5]

DIR is a specialists stage folder (``<workdir>/stages/specialists/<key>``: its ``index.json`` names the bin
folders, each with ``history.json`` and ``validations.json``) or a folder of copied files named
``<bin>.history.json`` / ``<bin>.validations.json`` (as under ``benchmarks/results/*/specialists/``), or one bin's
``history.json`` / ``validations.json`` (the folder names the bin).  One panel
per bin: the sampled episodes' success (a running mean over ``--smooth`` iterations) and the deterministic
validation, against frames.  The JSON gives per bin the validation at the start, its best and its last, and the
least-squares slope of the sampled success per iteration with its correlation.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from components.errors import MultigraspError
from tasks.specialist_index import rebase_entry


def find_bins(folder: Path) -> dict[str, tuple[list[dict], list[dict]]]:
    """bin label -> (history rows, validation rows) of ``folder`` (module docstring)."""
    out = {}
    index = folder / "index.json"
    if index.is_file():
        for label, entry in json.loads(index.read_text()).items():
            # the bins are the index's siblings in a stage folder, wherever it is now; else inside the index's folder
            # (a copied layout), else where the index recorded them
            candidates = (Path(rebase_entry(entry, folder.parent)["folder"]), folder / Path(entry["folder"]).name,
                          Path(entry["folder"]))
            unit = next((path for path in candidates if path.is_dir()), candidates[0])
            validations = unit / "validations.json"
            out[label] = (json.loads((unit / "history.json").read_text()),
                          json.loads(validations.read_text())["rows"] if validations.is_file() else [])
        return out
    if (folder / "history.json").is_file():  # one bin's files, copied without a prefix: the folder names the bin
        validations = folder / "validations.json"
        return {folder.name: (json.loads((folder / "history.json").read_text()),
                              json.loads(validations.read_text())["rows"] if validations.is_file() else [])}
    for path in sorted(folder.glob("*.history.json")):
        label = path.name[: -len(".history.json")]
        validations = folder / f"{label}.validations.json"
        out[label] = (json.loads(path.read_text()),
                      json.loads(validations.read_text())["rows"] if validations.is_file() else [])
    if not out:
        raise MultigraspError(f"{folder}: neither an index.json nor *.history.json files; give a specialists stage "
                              "folder or a folder of copied histories")
    return out


def summarise(history: list[dict], validations: list[dict]) -> dict:
    """Start / best / last validation success, and the slope (points per iteration) and correlation of the sampled
    success over the iterations."""
    rows = [h for h in history if "success" in h]
    summary: dict = {"iterations": len(history), "frames": int(history[-1]["frames"]) if history else 0}
    if len(rows) >= 3:
        x = np.array([h["iteration"] for h in rows], float)
        y = 100.0 * np.array([h["success"] for h in rows], float)
        slope = np.polyfit(x, y, 1)[0]
        summary.update(sampled_first=round(float(y[: max(1, len(y) // 5)].mean()), 2),
                       sampled_last=round(float(y[-max(1, len(y) // 5):].mean()), 2),
                       slope_points_per_iteration=round(float(slope), 4),
                       correlation=round(float(np.corrcoef(x, y)[0, 1]), 3) if y.std() > 0 else 0.0)
    if validations:
        best = max(validations, key=lambda v: (v["success"], v.get("lift", 0.0)))  # the stage's rule: ties by lift
        summary.update(validation_start=round(100.0 * validations[0]["success"], 2),
                       validation_best=round(100.0 * best["success"], 2), best_iteration=int(best["iteration"]),
                       validation_last=round(100.0 * validations[-1]["success"], 2))
    return summary


def plot(bins: dict[str, tuple[list[dict], list[dict]]], path: Path, smooth: int, title: str) -> Path:
    from matplotlib.figure import Figure

    n = len(bins)
    cols = min(n, 4)
    rows = (n + cols - 1) // cols
    fig = Figure(figsize=(3.2 * cols, 2.6 * rows))
    for i, (label, (history, validations)) in enumerate(bins.items()):
        ax = fig.add_subplot(rows, cols, i + 1)
        sampled = [h for h in history if "success" in h]
        if sampled:
            y = np.array([h["success"] for h in sampled], float)
            k = max(1, min(smooth, len(y)))
            mean = np.convolve(y, np.ones(k) / k, mode="valid")
            ax.plot([h["frames"] / 1e3 for h in sampled][k - 1:], 100.0 * mean, label=f"sampled (mean of {k})")
        if validations:
            frames = {0: 0, **{h["iteration"]: h["frames"] for h in history}}
            ax.plot([frames.get(v["iteration"], 0) / 1e3 for v in validations], [100.0 * v["success"] for v in validations],
                    "o-", label="validation")
        ax.set_title(label, fontsize=9)
        ax.set_xlabel("frames (thousands)", fontsize=8)
        ax.set_ylabel("success (%)", fontsize=8)
        ax.tick_params(labelsize=7)
        if i == 0:
            ax.legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.learning_curves", description=__doc__.split("\n\n")[0])
    parser.add_argument("folders", type=Path, nargs="+", help="specialists stage folders or folders of copied histories")
    parser.add_argument("--out", type=Path, required=True, help="the figure (PNG)")
    parser.add_argument("--json", type=Path, default=None, help="per-bin summary")
    parser.add_argument("--smooth", type=int, default=5, help="running mean of the sampled success (iterations)")
    parser.add_argument("--title", default="specialists: success during PPO training")
    args = parser.parse_args(argv)
    try:
        bins = {}
        for folder in args.folders:
            found = find_bins(folder)
            bins.update({(f"{folder.name}: {k}" if len(args.folders) > 1 and k != folder.name else k): v
                         for k, v in found.items()})
        plot(bins, args.out, args.smooth, args.title)
    except (MultigraspError, OSError, ValueError, KeyError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    summary = {label: summarise(*v) for label, v in bins.items()}
    for label, s in summary.items():
        print(f"{label}: {s}")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(summary, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())

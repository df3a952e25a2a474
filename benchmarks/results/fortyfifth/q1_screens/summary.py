"""Forty-fifth session: compare screening runs (screen.sh) with the profile's run of the same eight scenes.

    python benchmarks/results/fortyfifth/q1_screens/summary.py A.jsonl [B.jsonl ...] [--json OUT]

Accepted of all candidates, and Q1 (min over objects), Q1 averaged over objects, PN, Div and seconds, each weighted by
the accepted grasps of each scene; the reference is ../../fortyfourth/pair_roll/across.jsonl."""
import json
import sys
from pathlib import Path

REFERENCE = Path(__file__).resolve().parents[2] / "fortyfourth" / "pair_roll" / "across.jsonl"


def load(path):
    return {(tuple(d["objects"]), d["seed"]): d for d in map(json.loads, Path(path).read_text().splitlines())}


def aggregate(runs, keys):
    accepted = sum(runs[k]["reasons"]["accepted"] for k in keys)
    total = sum(runs[k]["batch"] for k in keys)
    weighted = [(runs[k]["reasons"]["accepted"], runs[k]) for k in keys if runs[k]["reasons"]["accepted"]]

    def mean(field):  # over the scenes that have the figure (Div needs two accepted grasps)
        pairs = [(a, field(d)) for a, d in weighted if field(d) is not None]
        n = sum(a for a, _ in pairs)
        return round(sum(a * v for a, v in pairs) / n, 4) if n else None

    return {"accepted": accepted, "candidates": total, "accept_rate": round(accepted / total, 4),
            "q1": mean(lambda d: d["q1"]), "q1_object_mean": mean(lambda d: sum(d["q1_per_object"]) / 2),
            "pn_mm": mean(lambda d: d["pn_mm"]), "div_deg": mean(lambda d: d["div_deg"]),
            "seconds": round(sum(runs[k]["seconds"] for k in keys), 1),
            "q1_above_reference_in": None}


def main(argv):
    out = None
    if "--json" in argv:
        i = argv.index("--json")
        out, argv = argv[i + 1], argv[:i] + argv[i + 2:]
    reference = load(REFERENCE)
    rows = {"reference (across.jsonl)": aggregate(reference, sorted(reference))}
    for path in argv:
        runs = load(path)
        keys = sorted(set(runs) & set(reference))
        row = aggregate(runs, keys)
        row["q1_above_reference_in"] = (f"{sum(1 for k in keys if runs[k]['q1'] is not None and reference[k]['q1'] is not None and runs[k]['q1'] > reference[k]['q1'])}"
                                        f" of {len(keys)} scenes")
        rows[Path(path).stem] = row
    for name, row in rows.items():
        print(f"{name:28s} {row}")
    if out:
        Path(out).write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main(sys.argv[1:])

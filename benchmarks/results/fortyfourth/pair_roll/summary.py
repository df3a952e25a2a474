"""Summary of synthesis_experiment JSON-lines files (forty-fourth session, docs/experiments.md "Fingers along the
object line"): accepted, Q1, per-object Q1, PN, Div per file and the per-scene Q1 difference against the first file.

    .venv/bin/python benchmarks/results/fortyfourth/pair_roll/summary.py BASE.jsonl OTHER.jsonl ...
"""
import json, sys, numpy as np
rows = {}
for path in sys.argv[1:]:
    for line in open(path):
        r = json.loads(line)
        key = (tuple(r["objects"]), r["seed"])
        rows.setdefault(path, {})[key] = r
base = sys.argv[1]
for path, d in rows.items():
    acc = sum(r["reasons"]["accepted"] for r in d.values()); n = sum(r["batch"] for r in d.values())
    w = [r["quality_n"] for r in d.values()]
    q1 = sum((r["q1"] or 0) * r["quality_n"] for r in d.values()) / max(1, sum(w))
    pn = sum((r["pn_mm"] or 0) * r["quality_n"] for r in d.values()) / max(1, sum(w))
    po = sum(np.mean(r["q1_per_object"]) * r["quality_n"] for r in d.values() if r["quality_n"]) / max(1, sum(w))
    div = np.mean([r["div_deg"] for r in d.values() if r["div_deg"]])
    common = [k for k in d if k in rows[base]]
    dq = [ (d[k]["q1"] or 0) - (rows[base][k]["q1"] or 0) for k in common if d[k]["quality_n"] and rows[base][k]["quality_n"]]
    print(f"{path}: scenes {len(d)} accepted {acc}/{n} ({acc/n:.1%}) q1 {q1:.4f} obj-mean {po:.4f} pn {pn:.2f} div {div:.1f}"
          f" | per-scene q1 diff vs base {np.mean(dq):+.4f} (higher in {sum(x>0 for x in dq)}/{len(dq)})")
    for k in sorted(d):
        r = d[k]; print("   ", k, r["reasons"]["accepted"], r["q1"], r["q1_per_object"], r["pn_mm"])

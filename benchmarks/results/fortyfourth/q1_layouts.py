"""One-off record (forty-fourth session): per-object Q1 of accepted pair grasps by the fingers that hold each object.

    .venv/bin/python benchmarks/results/fortyfourth/q1_layouts.py GRASPS.parquet WORKDIR OUT.json

GRASPS: a bench synthesize stage's grasps.parquet (the data of benchmarks/results/fortyfirst/bench_pairs.sh);
WORKDIR: its work dir (object cache).  Layout = the fingers of an object's 3 chosen contacts (contact_regions).
"""

import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from benchmarks.grasp_tables import read_accepted, scene_batches
from components.hand import HandModel
from components.metrics import q1_grasps
from components.objects import ObjectLibrary
from components.synthesis.hand_surface import HandSurface
from flows.config import load_config
from tasks.preflight import cache_dir

grasps, workdir, out = Path(sys.argv[1]), Path(sys.argv[2]), Path(sys.argv[3])
cfg = load_config("bench", None, [], workdir=workdir)
frame = read_accepted(grasps, "Pl", 100_000)
hand = HandModel(cfg.hand)
library = ObjectLibrary(cfg.objects, cache_dir=cache_dir(cfg.run.workdir))
metrics = cfg.synthesis.metrics
surface = HandSurface(hand, metrics.q1_hand_point_spacing_m)
per = np.zeros((len(frame), 2))
for rows, objects, p, R, q in scene_batches(frame, hand, library):
    per[rows] = q1_grasps(hand, objects, p, R, q, metrics, surface)[1].numpy()
names = hand.region_names
rows = []
for i, row in frame.iterrows():
    regions = np.asarray(row["contact_regions"]).reshape(2, -1)
    for j in range(2):
        layout = "+".join(sorted({names[k].split("_")[0] for k in regions[j]}))
        rows.append({"grasp": i, "layout": layout, "q1": per[i, j], "limits": per[i, j] == per[i].min()})
table = pd.DataFrame(rows)
summary = {
    "grasps": str(grasps), "n_grasps": len(frame),
    "q1_min_over_objects": round(float(per.min(1).mean()), 4), "q1_object_mean": round(float(per.mean()), 4),
    "layouts": {layout: {"objects": int(len(g)), "q1_mean": round(float(g["q1"].mean()), 4),
                         "q1_positive": round(float((g["q1"] > 0).mean()), 4),
                         "limits_the_grasp": int(g["limits"].sum())}
                for layout, g in table.groupby("layout")},
}
out.write_text(json.dumps(summary, indent=2))
print(json.dumps(summary, indent=2))

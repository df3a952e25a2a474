"""Forty-sixth session, docs/experiments.md "Opposed contacts in the energy" (a one-off record): does the opposition of
the chosen contacts (max -n_i . n_k of the objects' normals at an object's 3 contacts) predict the scripted squeeze's
success per pose?  Reads a benchmarks.lift_failures JSON (its episodes, trials 0-4) and the grasps table it names
(a path on the machine that made it).  Run from the repository root:

    PYTHONPATH=. .venv/bin/python benchmarks/results/fortysixth/opposition/opp_vs_lift.py LIFT.json
"""
import json, sys, tempfile, numpy as np, pandas as pd, torch
from flows.config import load_config
from components.hand import HandModel
from components.objects import ObjectLibrary
from components.synthesis.energy import contact_opposition_energy
from benchmarks.grasp_tables import scene_batches
from benchmarks.scripted_lift import select_grasps
lift = json.load(open(sys.argv[1]))
frame = select_grasps(lift["grasps"], "Pl", n_objects=2)
poses = pd.concat([g.iloc[:5] for _, g in frame.groupby("combination", sort=True)])
poses = poses.assign(pose=np.concatenate([np.arange(len(g.iloc[:5])) for _, g in frame.groupby("combination", sort=True)]))
poses = poses.reset_index(drop=True)
cfg = load_config(profile="bench")
hand = HandModel(cfg.hand); library = ObjectLibrary(cfg.objects, cache_dir=tempfile.mkdtemp())
opp = np.zeros((len(poses), 2))
for rows, objects, p, R, q in scene_batches(poses, hand, library):
    contacts = torch.as_tensor(np.stack(poses["contacts"].iloc[rows].to_numpy()).astype(np.int64)).reshape(len(rows), 2, -1)
    with torch.no_grad():
        cp, cn = hand.contact_candidates_and_normals(p, R, q)
        for j in range(2):
            pts = torch.gather(cp, 1, contacts[:, j].unsqueeze(-1).expand(-1, -1, 3))
            _, n = objects.object_sdf_and_normal(j, pts)
            # rounded as benchmarks.lift_failures rounds it: a pair exactly 120 deg apart (two faces of the hex prism)
            # reads 0.5, not opposed, instead of falling either side of the threshold by float noise
            opp[rows, j] = np.round((1.0 - contact_opposition_energy(n, 1.0)).numpy(), 4)
ep = pd.DataFrame(lift["episodes"])
ep = ep[ep["trial"] < 5]
succ = ep.groupby(["combination", "pose"])["success"].mean()
s = np.array([succ.get((c, k), np.nan) for c, k in zip(poses["combination"], poses["pose"])])
both = (opp > 0.5).all(1)
print("poses", len(poses), "both chosen-contact opposed", both.mean().round(3))
print("success if both opposed", np.nanmean(s[both]).round(3), "otherwise", np.nanmean(s[~both]).round(3))
print("objects opposed", (opp > 0.5).mean().round(3), "q1 if both", poses["q1"][both].mean().round(3), "else", poses["q1"][~both].mean().round(3))

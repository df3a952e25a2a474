"""One-off probe: does an episode-constant action near the squeeze lift the 10 training poses more often than the
squeeze itself?  Random constant offsets delta ~ N(0, s^2) (in action units, clipped to [-1, 1]) on the squeeze."""
import json, sys, tempfile, time
from pathlib import Path
import numpy as np, torch
sys.path.insert(0, str(Path(__file__).resolve().parents[4]))
from flows.config import load_config
from flows.pipeline import stage_output
from tasks.grasp_tables import grasp_rows
from tasks.specialists import records_from_table
from benchmarks.scripted_lift import scripted_setup
from components.execution import LiftEnv
from components.execution.evaluation import evaluate_lift, ScriptedLift

sets = [l for l in open(Path(__file__).with_name("sets.txt")).read().split("\n") if l]
cfg = load_config("bench", None, sets, workdir=Path(sys.argv[5]))
man = stage_output(cfg, "synthesize")
frame = grasp_rows(man, "lowest_energy", 1, ["train"], 2)
records = records_from_table(frame)
hand, library, encoder, squeeze, lift = scripted_setup(cfg, "squeeze")
base = squeeze.action.clone()
scales = [float(s) for s in sys.argv[1].split(",")]
K, trials = int(sys.argv[2]), int(sys.argv[3])
rng = np.random.default_rng(0)
out = {"base": base.tolist(), "n_poses": len(records), "runs": []}
with tempfile.TemporaryDirectory() as tmp:
    urdf = hand.export_urdf(Path(tmp) / "hand")
    env = LiftEnv(hand, library, urdf, records, lift, encoder, record_order="cycle")
    t = time.time()
    r0 = evaluate_lift(env, squeeze, trials=trials, seed=7)
    out["squeeze"] = r0.successes_per_pose
    print("squeeze", r0.successes_per_pose, f"{time.time()-t:.0f}s", flush=True)
    for s in scales:
        for k in range(K):
            delta = torch.as_tensor(rng.normal(0, s, base.shape), dtype=base.dtype)
            pol = ScriptedLift(); pol.action = (base + delta).clamp(-1, 1)
            r = evaluate_lift(env, pol, trials=trials, seed=7)
            out["runs"].append({"scale": s, "k": k, "delta": delta.tolist(), "per_pose": r.successes_per_pose})
            print(s, k, r.successes_per_pose, sum(r.successes_per_pose), f"{time.time()-t:.0f}s", flush=True)
            json.dump(out, open(sys.argv[4], "w"))
    env.close()

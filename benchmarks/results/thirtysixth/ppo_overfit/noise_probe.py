"""One-off probe (thirty-sixth session): the scripted squeeze with white Gaussian noise (drawn afresh every step) on
one group of action entries, on the 10 training pre-grasps of run.sh x 3 trials, under both joint action modes.
Which entries can PPO's exploration noise disturb without dropping the grasp?
    python benchmarks/results/thirtysixth/ppo_overfit/noise_probe.py SIGMA OUT.json WORKDIR"""
import json, sys, tempfile, time
from pathlib import Path
import torch
sys.path.insert(0, str(Path(__file__).resolve().parents[4]))
from flows.config import load_config
from flows.pipeline import stage_output
from tasks.grasp_tables import grasp_rows
from tasks.specialists import records_from_table
from benchmarks.scripted_lift import scripted_setup
from components.execution import LiftEnv
from components.execution.evaluation import evaluate_lift

class NoisyLift:
    """The squeeze's constant action plus N(0, sigma^2) on the entries ``idx``, drawn afresh every step."""

    def __init__(self, action, idx):
        self.action, self.idx = action, idx

    def __call__(self, td):
        action = self.action.clone()
        action[self.idx] += sigma * torch.randn(len(self.idx), generator=gen)
        return td.set("action", action.clamp(-1, 1))


sigma, out_path, workdir = float(sys.argv[1]), sys.argv[2], Path(sys.argv[3])
sets = [l for l in open(Path(__file__).with_name("sets.txt")).read().split("\n") if l]
GROUPS = {"none": [], "joints": list(range(18)), "base force": [18, 19, 20], "base torque": [21, 22, 23]}
out = {"sigma": sigma, "trials": 3, "rows": []}
gen = torch.Generator().manual_seed(0)
for mode in ("delta", "offset"):
    cfg = load_config("bench", None, sets + [f"lift.joint_action_mode={mode}"], workdir=workdir)
    records = records_from_table(grasp_rows(stage_output(cfg, "synthesize"), "lowest_energy", 1, ["train"], 2))
    hand, library, encoder, squeeze, lift = scripted_setup(cfg, "squeeze")
    with tempfile.TemporaryDirectory() as tmp:
        env = LiftEnv(hand, library, hand.export_urdf(Path(tmp) / "hand"), records, lift, encoder, record_order="cycle")
        for name, idx in GROUPS.items():
            policy = NoisyLift(squeeze.action, idx)
            t = time.time()
            r = evaluate_lift(env, policy, trials=3, seed=7)
            out["rows"].append({"mode": mode, "noise_on": name, "succ": r.succ, "per_pose": r.successes_per_pose})
            print(mode, name, r.succ, r.successes_per_pose, f"{time.time() - t:.0f}s", flush=True)
            json.dump(out, open(out_path, "w"), indent=1)
        env.close()

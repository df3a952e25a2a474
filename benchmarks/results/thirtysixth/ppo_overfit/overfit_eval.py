"""One-off: the overfit specialist (10 training pre-grasps) and the squeeze on the same 10 poses x T trials."""
import json, sys, time
from pathlib import Path
sys.path.insert(0, str(Path(__file__).resolve().parents[4]))
from flows.config import load_config
from flows.pipeline import stage_output
from components.execution.factory import LiftEnvFactory
from components.execution.ppo import load_actor
from components.execution.evaluation import evaluate_lift
from tasks.preflight import cache_dir
from tasks.specialists import squeeze_lift
from components.hand import HandModel

unit = Path(sys.argv[1]); trials = int(sys.argv[2]); seed = int(sys.argv[3])
sets = [l for l in open(Path(__file__).with_name("sets.txt")).read().split("\n") if l] + sys.argv[6:]  # extra KEY=VALUE
cfg = load_config("bench", None, sets, workdir=Path(sys.argv[5]))
enc = stage_output(cfg, "pointnet")
encoder = enc.path("encoder")
print("encoder", encoder, flush=True)
f = LiftEnvFactory(hand_cfg=cfg.hand.model_dump(mode="json"), objects_cfg=cfg.objects.model_dump(mode="json"),
                   objects_cache=str(cache_dir(cfg.run.workdir)), urdf=str(unit / "hand.urdf"),
                   records=str(unit / "records.json"), lift_cfg=cfg.lift.model_dump(mode="json"), encoder=str(encoder),
                   record_order="cycle")
env = f()
hand = HandModel(cfg.hand)
out = {}
for name in ("squeeze", "best", "last"):
    t = time.time()
    pol = squeeze_lift(cfg.specialists, hand.actuated_joint_names) if name == "squeeze" else load_actor(unit / "policy.pt", env, name)
    r = evaluate_lift(env, pol, trials=trials, seed=seed)
    out[name] = {"succ": r.succ, "per_pose": r.successes_per_pose, "n_poses": r.n_poses, "trials": trials}
    print(name, r.succ, r.successes_per_pose, f"{time.time()-t:.0f}s", flush=True)
json.dump(out, open(sys.argv[4], "w"), indent=1)

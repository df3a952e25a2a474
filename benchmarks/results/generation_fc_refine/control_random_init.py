"""Control: the force-closure refinement from the synthesis' random initial poses instead of generated ones
(same 3 mini Pl scenes, 32 each, w_pen 1000, 400 steps).

    python benchmarks/results/generation_fc_refine/control_random_init.py WORKDIR OUT.json

WORKDIR: a mini run's work dir with its scenes stage (run from the repository root)."""
import json, sys, time, torch
from pathlib import Path
from flows.config import load_config
from flows.pipeline import stage_output
from components.hand import HandModel
from components.objects import ObjectLibrary, Scene
from components.synthesis import SceneObjects
from components.synthesis.energy import GraspProblem
from components.synthesis.initializations import initial_poses
from components.synthesis.pose import unpack
from components.generation import RefineConfig
from components.generation.refine import force_closure_refinement
from components.metrics import penetration_depth, q1_grasps
from tasks.preflight import cache_dir
from tasks.synthesize import read_scene_records
torch.set_num_threads(2)
cfg = load_config("mini", None, [], workdir=Path(sys.argv[1]))
hand = HandModel(cfg.hand); library = ObjectLibrary(cfg.objects, cache_dir=cache_dir(cfg.run.workdir))
records = [r for r in read_scene_records(stage_output(cfg, "scenes")) if r["split"] == "Pl"][:3]
rc = RefineConfig(steps=0, fc_steps=400, fc_w_pen=1000)
q1s, pns = [], []
for number, record in enumerate(records):
    scene = Scene.from_dict(record["scene"]); objects = SceneObjects(library, scene, hand.device, hand.dtype)
    syn = cfg.synthesis.optimizer_for(len(scene.objects)).model_copy(update={"batch_size": 32})
    problem = GraspProblem.build(hand, objects, syn)
    x, _ = initial_poses(problem, torch.Generator().manual_seed(number))
    p, R, q = unpack(x)
    t = time.time(); p, R, q = force_closure_refinement(hand, objects, p, R, problem.effective_joints(q), syn, rc)
    q1, _ = q1_grasps(hand, objects, p, R, q, cfg.synthesis.metrics)
    pn = penetration_depth(hand, objects, p, R, q, cfg.synthesis.metrics).pn_mm
    q1s += q1.tolist(); pns += pn.tolist(); print(number, time.time() - t, float(q1.mean()), float(pn.mean()), file=sys.stderr)
out = {"what": __doc__, "n": len(q1s), "q1": sum(q1s) / len(q1s), "pn_mm": sum(pns) / len(pns)}
print(json.dumps(out)); json.dump(out, open(sys.argv[2], "w"), indent=1)

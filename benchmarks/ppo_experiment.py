"""Does PPO improve a lift policy on given pre-grasps?  Deterministic success before and after training.

    python -m benchmarks.ppo_experiment --records <workdir>/stages/specialists/<unit>/records.json \\
        --encoder <workdir>/stages/pointnet/<unit>/encoder.pt --profile bench --workdir <workdir> \\
        --iterations 60 [--set specialists.init_policy=zero --set specialists.ppo.init_scale=0.25 ...] --json OUT

A specialist's training history shows its *stochastic* success (the actions sampled for exploration); what the
evaluation counts is the deterministic policy.  This tool trains one PPO policy on the records of a specialist
bin (``specialists.ppo`` and ``specialists.init_policy`` of the config, ``lift`` for the env, 2 collector
workers as the bench profile) and lifts the same fixed subset of the records, every ``--eval-stride``-th, with
the deterministic policy before training (the untrained actor: ``init_policy``'s mean action) and after, one
seeded trial each (:func:`components.execution.evaluation.evaluate_lift`, the protocol of ``evaluate execution``).  The hand
URDF is exported for the configured hand into the work dir's cache (as the evaluation does).  ``--checkpoint`` keeps the
PPO checkpoint there, so a rerun resumes; by default it lives in a temporary folder.

The JSON has the setting (config overrides, PPO config, records), ``before`` / ``after`` (wins, poses), the
training curve in blocks of 10 iterations (mean stochastic success, reward, final lift) and the full history.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

from benchmarks.grasp_tables import check_positive, finish_tool
from components.errors import MultigraspError


def curve_blocks(history: list[dict], block: int = 10) -> list[dict]:
    """Means of the history's stochastic success, reward and final lift over blocks of ``block`` iterations (None
    where no episode ended in the block)."""
    out = []
    for start in range(0, len(history), block):
        rows = history[start:start + block]
        def mean(key: str):  # over the iterations that have it (success / final lift need an ended episode)
            values = [r[key] for r in rows if key in r]
            return round(sum(values) / len(values), 4) if values else None

        out.append({"iterations": f"{rows[0]['iteration']}-{rows[-1]['iteration']}", "frames": rows[-1]["frames"],
                    "success": mean("success"), "reward": mean("reward"), "final_lift_m": mean("final_lift")})
    return out


def run(cfg, records: Path, encoder: Path, iterations: int, stride: int, checkpoint: Path) -> dict:
    from components.execution.evaluation import evaluate_lift
    from components.execution.factory import LiftEnvFactory
    from components.execution.ppo import build_actor_critic, train_ppo
    from components.hand import HandModel
    from components.hand.model import URDF_FILE_NAME
    from tasks.preflight import cache_dir
    from tasks.specialists import initial_action

    for path, what in ((records, "--records"), (encoder, "--encoder")):
        if not path.is_file():
            raise MultigraspError(f"{what}: {path} not found (a specialists unit folder has records.json; "
                                  "the pointnet stage writes encoder.pt)")
    stage = cfg.specialists
    ppo = stage.ppo.model_copy(update={"iterations": iterations})
    hand = HandModel(cfg.hand)
    # this installation's URDF (the copy in a unit folder names the mesh files of the installation that trained it)
    urdf = hand.export_urdf(cache_dir(cfg.run.workdir) / "hand" / URDF_FILE_NAME)
    init = initial_action(stage, hand.actuated_joint_names)
    factory = LiftEnvFactory(hand_cfg=cfg.hand.model_dump(mode="json"), objects_cfg=cfg.objects.model_dump(mode="json"),
                             objects_cache=str(cache_dir(cfg.run.workdir)), urdf=str(urdf), records=str(records),
                             lift_cfg=cfg.lift.model_dump(mode="json"), encoder=str(encoder), seed=ppo.seed)
    env = factory()
    try:
        poses = list(range(0, len(env.records), stride))
        start_actor, _, _ = build_actor_critic(env, ppo, init)
        before = sum(evaluate_lift(env, start_actor, trials=1, seed=stage.eval_seed, poses=poses).successes_per_pose)
        print(f"ppo experiment: untrained ({stage.init_policy}) {before}/{len(poses)}", file=sys.stderr, flush=True)

        def progress(iteration: int, total: int, info: dict) -> None:
            success = f" success {info['success']:.3f}" if "success" in info else ""
            print(f"ppo experiment: iteration {iteration}/{total} reward {info['reward']:.3f}{success} "
                  f"ETA {info['eta_s']:.0f}s", file=sys.stderr, flush=True)

        result = train_ppo(factory, ppo, checkpoint, progress, init_action=init)
        after = sum(evaluate_lift(env, result.actor, trials=1, seed=stage.eval_seed, poses=poses).successes_per_pose)
    finally:
        env.close()
    history = result.history
    return {"records": str(records), "n_records": len(env.records), "eval_poses": len(poses), "eval_stride": stride,
            "init_policy": stage.init_policy, "ppo": ppo.model_dump(mode="json"),
            "frames": int(history[-1]["frames"]) if history else 0,
            "before": {"wins": before, "poses": len(poses)}, "after": {"wins": after, "poses": len(poses)},
            "curve": curve_blocks(history), "history": history}


def main(argv: list[str] | None = None) -> int:
    from flows.config import load_config

    parser = argparse.ArgumentParser(prog="python -m benchmarks.ppo_experiment", description=__doc__.split("\n\n")[0])
    parser.add_argument("--records", type=Path, required=True, help="records.json of a specialists unit")
    parser.add_argument("--encoder", type=Path, required=True, help="encoder.pt of the pointnet stage")
    parser.add_argument("--profile", default="bench", help="profile for specialists / lift / hand / objects (default bench)")
    parser.add_argument("--workdir", type=Path, help="work dir whose object cache is used (default: the profile's)")
    parser.add_argument("--set", action="append", default=[], dest="sets", help="KEY=VALUE override, as for multigrasp run")
    parser.add_argument("--iterations", type=int, default=20, help="PPO iterations (default 20)")
    parser.add_argument("--eval-stride", type=int, default=13, help="evaluate every this-many-th record (default 13)")
    parser.add_argument("--checkpoint", type=Path, help="PPO checkpoint file (kept; a rerun resumes); default: temporary")
    parser.add_argument("--json", type=Path, required=True, help="write the result here")
    args = parser.parse_args(argv)
    if (status := check_positive(args, "iterations", "eval_stride")) is not None:
        return status

    def compute() -> dict:
        cfg = load_config(args.profile, None, args.sets, **({"workdir": args.workdir} if args.workdir else {}))
        with tempfile.TemporaryDirectory() as tmp:
            checkpoint = args.checkpoint or Path(tmp) / "policy.pt"
            return {"sets": args.sets, **run(cfg, args.records, args.encoder, args.iterations, args.eval_stride, checkpoint)}

    def report(result: dict) -> None:
        b, a = result["before"], result["after"]
        print(f"PPO ({result['init_policy']} start, {result['frames']} frames): deterministic success {b['wins']}/{b['poses']} "
              f"before -> {a['wins']}/{a['poses']} after")
        for block in result["curve"]:
            print(f"  iterations {block['iterations']}: stochastic success {block['success']}, reward {block['reward']}")

    return finish_tool(args.json, compute, report)


if __name__ == "__main__":
    sys.exit(main())

"""How many synthesised pre-grasps survive the scripted "w/o RL" lift, per object combination.

    python -m benchmarks.scripted_lift --profile bench --workdir runs/bench --split train --max-poses 30 --json OUT

The paper's "w/o RL" baseline lifts straight up from the pre-grasp (its success: 1.37 %).  This tool runs that
baseline (:class:`components.execution.evaluation.ScriptedLift`, the upward base force
``specialists.scripted_force_fraction``, from the pre-grasp itself: the env's grasp closure off), or with
``--controller squeeze`` the squeeze-and-lift that PPO starts from (the env's grasp closure, ``lift.closure_*``,
then ``specialists.squeeze_*``: close the flexion joints by ``squeeze_action`` -- 0 by default, the closure has
squeezed -- while pushing up more gently), in the lift env (``lift`` config) with the evaluation protocol of
``multigrasp evaluate execution`` (:func:`components.execution.evaluation.evaluate_lift`: ``--trials`` seeded
perturbations of each pre-grasp, success = every object above ``lift.eval_success_height_m`` at the end), on the
first ``--max-poses`` accepted grasps (optionally only those with ``--min-q1`` <= stored Q1 <= ``--max-q1``) of every
combination of a ``synthesize`` stage (found or given as in
:mod:`benchmarks.grasp_tables`).  It needs no trained policy: the point-cloud features are those of an untrained
PointNet, which the scripted policy never reads.  It measures how liftable the pre-grasps are before any RL.
Per combination: poses, trials, success rate, median and 90th percentile of the final lift of the lowest object.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

from benchmarks.grasp_tables import (PoseProgress, add_source_args, check_positive, finish_tool, read_accepted,
                                     resolve_source, row_report)
from components.errors import MultigraspError


def select_grasps(grasps: Path, split: str | None, q1_range: tuple[float, float] = (-np.inf, np.inf),
                  n_objects: int | None = None):
    """Every accepted grasp of ``split`` (None: all) whose stored Q1 lies in ``q1_range`` (inclusive) and whose
    scene holds ``n_objects`` objects (None: any); one-line :class:`MultigraspError` when a bound is given and the
    table has no Q1, or nothing is left."""
    frame = read_accepted(grasps, split, sys.maxsize)  # every accepted row; --max-poses caps each combination
    if n_objects is not None:
        frame = frame[frame["object_names"].map(len) == n_objects]
        if not len(frame):
            raise MultigraspError(f"no accepted grasps of {n_objects}-object scenes in {grasps} — choose another "
                                  "--n-objects or --split")
    if np.isfinite(q1_range).any():
        if "q1" not in frame:
            raise MultigraspError(f"{grasps} has no q1 column; --min-q1 / --max-q1 need a synthesize stage's table")
        frame = frame[(frame["q1"] >= q1_range[0]) & (frame["q1"] <= q1_range[1])]
        if not len(frame):
            raise MultigraspError(f"no accepted grasps with Q1 in [{q1_range[0]}, {q1_range[1]}] in {grasps}")
    return frame


def scripted_setup(cfg, controller: str):
    """(hand, object library, encoder, policy, lift env config) of a scripted lift: ``straight`` is the paper's
    w/o RL (``specialists.scripted_force_fraction``, from the pre-grasp itself: no grasp closure), ``squeeze`` the
    squeeze-and-lift PPO starts from (``specialists.squeeze_*``, the env as configured)."""
    from components.execution.evaluation import ScriptedLift
    from components.execution.pointnet import PointNetEncoder
    from components.hand import HandModel
    from components.objects import ObjectLibrary
    from tasks.preflight import cache_dir
    from tasks.specialists import squeeze_lift

    hand = HandModel(cfg.hand)
    library = ObjectLibrary(cfg.objects, cache_dir=cache_dir(cfg.run.workdir))
    # untrained, of the configured size: the scripted policy never reads the features (module docstring)
    encoder = PointNetEncoder(cfg.pointnet.encoder.model_copy(update={"feature_dim": cfg.lift.feature_dim})).freeze()
    stage = cfg.specialists
    policy = (ScriptedLift(stage.scripted_force_fraction) if controller == "straight"
              else squeeze_lift(stage, hand.actuated_joint_names))
    lift = cfg.lift.model_copy(update={"closure_steps": 0}) if controller == "straight" else cfg.lift
    return hand, library, encoder, policy, lift


def run(grasps: Path, cfg, split: str | None, max_poses: int, trials: int, controller: str = "straight",
        q1_range: tuple[float, float] = (-np.inf, np.inf), n_objects: int | None = None) -> dict:
    """The scripted lift on every combination's first ``max_poses`` accepted grasps whose stored Q1 lies in
    ``q1_range`` (inclusive) and whose scene holds ``n_objects`` objects (None: any; module docstring)."""
    from components.execution import LiftEnv
    from components.execution.evaluation import evaluate_lift
    from tasks.specialists import records_from_table

    frame = select_grasps(grasps, split, q1_range, n_objects)
    hand, library, encoder, policy, lift = scripted_setup(cfg, controller)
    stage = cfg.specialists
    rows = []
    progress = PoseProgress("scripted lift", int(frame.groupby("combination").head(max_poses).shape[0]))
    def pose_done(pose: int, trial: int, rollout) -> None:
        if trial == trials - 1:
            progress.done()
    with tempfile.TemporaryDirectory() as tmp:
        urdf = hand.export_urdf(Path(tmp) / "hand")
        for combination, group in frame.groupby("combination", sort=True):
            records = records_from_table(group.iloc[:max_poses])
            env = LiftEnv(hand, library, urdf, records, lift, encoder, record_order="cycle")
            try:
                result = evaluate_lift(env, policy, trials=trials, seed=cfg.specialists.eval_seed,
                                       on_rollout=pose_done)
            finally:
                env.close()
            lifts = np.asarray(result.final_lifts)
            rows.append({"combination": combination, "n_poses": result.n_poses, "trials": trials,
                         "succ": round(result.succ, 4), "median_final_lift_m": round(float(np.median(lifts)), 4),
                         "p90_final_lift_m": round(float(np.quantile(lifts, 0.9)), 4)})
            print(f"scripted lift: {combination} done", file=sys.stderr, flush=True)
    total = sum(r["n_poses"] * r["trials"] for r in rows)
    wins = sum(r["succ"] * r["n_poses"] * r["trials"] for r in rows)
    setting = ({"force_fraction": stage.scripted_force_fraction} if controller == "straight" else
               {"force_fraction": stage.squeeze_force_fraction, "squeeze_action": stage.squeeze_action,
                "squeeze_joints": list(stage.squeeze_joints)})
    bounds = {k: float(v) for k, v in zip(("min_q1", "max_q1"), q1_range) if np.isfinite(v)}
    return {"grasps": str(grasps), "split": split, "n_objects": n_objects, "controller": controller, **setting, **bounds,
            "closure_steps": lift.closure_steps,
            **({"q1_mean": round(float(frame.groupby("combination").head(max_poses)["q1"].mean()), 4)}
               if "q1" in frame else {}),
            "succ_all": round(wins / total, 4) if total else 0.0, "rows": rows}


def add_lift_args(parser: argparse.ArgumentParser, max_poses: int, trials: int, controller: str) -> None:
    """The options that say which grasps are lifted, how often and by which scripted controller."""
    parser.add_argument("--max-poses", type=int, default=max_poses,
                        help=f"accepted grasps per combination (default {max_poses})")
    parser.add_argument("--trials", type=int, default=trials,
                        help=f"seeded perturbed trials per grasp (default {trials}; the paper: 5)")
    parser.add_argument("--controller", choices=("straight", "squeeze"), default=controller,
                        help=f"straight: the paper's w/o RL (specialists.scripted_force_fraction); squeeze: the env's "
                        f"grasp closure, then the squeeze-and-lift PPO starts from (specialists.squeeze_*); default "
                        f"{controller}")
    parser.add_argument("--n-objects", type=int, default=None,
                        help="only grasps of scenes with this many objects (2: the pairs; default: every scene)")


def check_lift_args(args: argparse.Namespace) -> int | None:
    """Exit status 2 after a one-line error when an option of :func:`add_lift_args` is out of range."""
    if (status := check_positive(args, "max_poses", "trials")) is not None:
        return status
    if args.n_objects is not None and args.n_objects < 1:
        print("error: --n-objects must be at least 1 (2: the pairs)", file=sys.stderr)
        return 2
    return None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.scripted_lift", description=__doc__.split("\n\n")[0])
    add_source_args(parser)
    add_lift_args(parser, max_poses=30, trials=5, controller="straight")
    parser.add_argument("--min-q1", type=float, default=-np.inf, help="only grasps whose stored Q1 is at least this")
    parser.add_argument("--max-q1", type=float, default=np.inf, help="only grasps whose stored Q1 is at most this")
    parser.add_argument("--json", type=Path, required=True, help="write the result here")
    args = parser.parse_args(argv)
    if (status := check_lift_args(args)) is not None:
        return status

    def compute() -> dict:
        cfg, grasps = resolve_source(args)
        return run(grasps, cfg, None if args.split == "all" else args.split, args.max_poses, args.trials,
                   args.controller, (args.min_q1, args.max_q1), args.n_objects)

    return finish_tool(args.json, compute, row_report(
        lambda row: f"{row['combination']:24s} {row['n_poses']:4d} poses x {row['trials']} trials: success "
                    f"{row['succ']:.1%}, final lift median {row['median_final_lift_m']:.3f} m, "
                    f"p90 {row['p90_final_lift_m']:.3f} m"))


if __name__ == "__main__":
    sys.exit(main())

"""Why scripted lifts fail: per episode and per object, what the hand touches at the pre-grasp, after the grasp
closure, and at the end.

    python -m benchmarks.lift_failures --profile bench --workdir runs/bench --split Pl --max-poses 5 --trials 2 \\
        --json OUT

For every combination's first ``--max-poses`` accepted grasps of a ``synthesize`` stage (found or given as in
:mod:`benchmarks.grasp_tables`), ``--trials`` perturbed episodes each of the scripted lift of
:mod:`benchmarks.scripted_lift` (``--controller squeeze`` by default: the env's grasp closure, then the squeeze-and-lift
PPO starts from; the trial seeds of ``benchmarks.scripted_lift``, keyed by the pose's place in its combination --
``multigrasp evaluate execution`` keys them by scene and row and picks other poses), and for each object of each
episode:

* **at the pre-grasp** (the perturbed trial start, before any physics step): the hand links within
  ``--near-mm`` (5 mm, the Q1 contact distance) of the object, PyBullet's closest points, the deepest penetration,
  and the *opposition* of those links' contact normals;
* **after the closure** (the episode's first observation): the same, the summed normal force of the contacts (N;
  only where the closure ran: not with ``straight``, nor without a link near an object), and how far the closure moved the object (mm);
* **at the end**: its lift and whether it is above ``lift.eval_success_height_m``.

Opposition of a set of unit contact normals n_1..n_k is max_{i<j} -n_i . n_j: 1 for two directly opposing contacts
(a pinch across the object), 0 for perpendicular ones, -1 for a single contact or none.  An object counts as
*opposed* when its opposition exceeds ``--opposed-above`` (0.5: two contacts more than 120 degrees apart).  The
summary splits the episodes into all / some / no objects lifted and gives each object's lift rate with and without
opposition at the pre-grasp, the quantity that separates the grasps that lift from those that do not (README
"Why the pre-grasps drop").  Each object of each episode is one row of the JSON's ``objects``.

Each object row also names the fingers of the grasp's *chosen* contacts on it (``contact_fingers``: the synthesis
energy's contacts, from the table's ``contact_regions``; ``palm`` for the palm's regions), and the summary's
``by_contact_finger`` gives, per finger, the lift rate of the objects whose chosen contacts use it and of those whose
do not, and the success rate of the episodes where some object uses it and of the others (README "Palm contacts").
The summary's ``by_q1_threshold`` gives, for each of ``--q1-thresholds``, the poses whose stored Q1 is at least it
and their success rate: what a stricter ``synthesis.min_q1`` would keep, and how well that lifts.

Where the table has the synthesis' ``contacts`` column, each object row also gives ``contact_opposition``: the
opposition of the objects' outward normals at the grasp's chosen contacts on it, at the stored (unperturbed)
pre-grasp -- what ``synthesis.optimizer.w_opposition`` asks for -- and the summary splits the success rate by it
(``episodes_every_object_contacts_opposed`` and the success of those episodes and of the others; docs/experiments.md
"Opposed contacts in the energy").
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from benchmarks.grasp_tables import PoseProgress, add_source_args, finish_tool, resolve_source, scene_batches
from benchmarks.scripted_lift import add_lift_args, check_lift_args, scripted_setup, select_grasps


def opposition(normals: np.ndarray) -> float:
    """max over pairs of -n_i . n_j of unit normals (k, 3) (module docstring); -1 for fewer than two."""
    n = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    if len(n) < 2:
        return -1.0
    dots = -(n @ n.T)
    return float(dots[np.triu_indices(len(n), 1)].max())


def touching(world, body: int, radius: float, with_force: bool) -> dict:
    """Hand links of ``world`` within ``radius`` (m) of object ``body``: count, opposition of their closest-point
    normals (one per link, its nearest point), the smallest signed distance (mm; < 0 inside; ``radius`` when no link is that near) and, ``with_force``
    (only right after physics steps: PyBullet keeps the last step's contacts), the summed normal force of the
    contact points (N)."""
    import pybullet as pb

    nearest: dict[int, tuple] = {}
    for cp in pb.getClosestPoints(world.body, body, radius, physicsClientId=world.client):
        if cp[3] not in nearest or cp[8] < nearest[cp[3]][8]:
            nearest[cp[3]] = cp
    out = {"links": len(nearest), "opposition": round(opposition([cp[7] for cp in nearest.values()]), 4),
           "min_distance_mm": round(1e3 * min((cp[8] for cp in nearest.values()), default=radius), 3)}
    if with_force:
        out["normal_force_n"] = round(float(sum(cp[9] for cp in pb.getContactPoints(
            world.body, body, physicsClientId=world.client))), 3)
    return out


def run(grasps: Path, cfg, split: str | None, max_poses: int, trials: int, controller: str, near_m: float,
        opposed_above: float, n_objects: int | None = None, q1_thresholds: Sequence[float] = ()) -> dict:
    """Every episode's per-object record and the summary (module docstring)."""
    import torch
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    from components.execution import LiftEnv
    from components.execution.evaluation import trial_seed
    from tasks.specialists import records_from_table

    frame = select_grasps(grasps, split, n_objects=n_objects)
    hand, library, encoder, policy, lift = scripted_setup(cfg, controller)
    height, seed = lift.eval_success_height_m, cfg.specialists.eval_seed
    objects, episodes = [], []
    progress = PoseProgress("lift failures", int(frame.groupby("combination").head(max_poses).shape[0]))
    with tempfile.TemporaryDirectory() as tmp:
        urdf = hand.export_urdf(Path(tmp) / "hand")
        for combination, group in frame.groupby("combination", sort=True):
            group = group.iloc[:max_poses]
            env = LiftEnv(hand, library, urdf, records_from_table(group), lift, encoder, record_order="cycle")
            world = env.world
            contact_opp = chosen_contact_opposition(group, hand, library)
            try:
                for pose in range(len(group)):
                    for trial in range(trials):
                        key = trial_seed(seed, pose, trial)
                        # the trial's start, as the env's reset builds it (LiftEnv._reset), measured before any step
                        start = world.reset(world.perturbed(env.records[pose], np.random.default_rng(key),
                                                            lift.trial_position_noise_m, lift.trial_joint_noise_rad))
                        before = [touching(world, body, near_m, False) for body in world.objects]
                        start_pos = start.obj_pos.copy()
                        env.set_next_record(pose, key)
                        stepped = world.physics_seconds
                        with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
                            first = env.reset()
                            closed = world.read()
                            # contact forces only when the closure stepped the physics (it does not without links
                            # near an object, or with closure_steps 0): PyBullet keeps the last step's contacts
                            after = [touching(world, body, near_m, world.physics_seconds != stepped)
                                     for body in world.objects]
                            rollout = env.rollout(lift.max_steps, policy=policy, break_when_any_done=True,
                                                  auto_reset=False, tensordict=first)
                        end = world.read()
                        lifts = end.obj_pos[:, 2] - env.episode.start_heights
                        moved = np.linalg.norm(closed.obj_pos - start_pos, axis=1)
                        q1 = float(group.iloc[pose]["q1"]) if "q1" in group else None
                        fingers = chosen_fingers(group.iloc[pose], hand.region_names)
                        for j, name in enumerate(env.records[pose].scene.names):
                            objects.append({
                                "combination": combination, "pose": pose, "trial": trial, "object": name, "q1": q1,
                                **({"contact_fingers": fingers[j]} if fingers is not None else {}),
                                **({"contact_opposition": float(contact_opp[pose, j])}
                                   if contact_opp is not None else {}),
                                "pregrasp": before[j], "after_closure": after[j],
                                "closure_moved_mm": round(1e3 * float(moved[j]), 3),
                                "final_lift_m": round(float(lifts[j]), 4), "lifted": bool(lifts[j] > height)})
                        episodes.append({"combination": combination, "pose": pose, "trial": trial,
                                         "success": bool(rollout[-1]["next", "success"]),
                                         "objects_lifted": int((lifts > height).sum()), "n_objects": len(lifts),
                                         "steps": int(rollout.shape[0])})
                    progress.done()
            finally:
                env.close()
            print(f"lift failures: {combination} done", file=sys.stderr, flush=True)
    return {"grasps": str(grasps), "split": split, "n_objects": n_objects, "controller": controller,
            "closure_steps": lift.closure_steps,
            "near_mm": round(near_m * 1e3, 3), "opposed_above": opposed_above,
            "summary": summarise(episodes, objects, opposed_above, q1_thresholds), "episodes": episodes, "objects": objects}


def chosen_fingers(row, region_names: list) -> list[list[str]] | None:
    """Per object, the sorted fingers (region-name prefix: ``ff`` ... ``th``, ``palm``) of the row's chosen contacts,
    from its flat ``contact_regions`` (n_obj * C region indices, object-major); None without that column."""
    if "contact_regions" not in row or row["contact_regions"] is None:
        return None
    regions = np.asarray(row["contact_regions"], dtype=np.int64).reshape(len(row["object_names"]), -1)
    return [sorted({region_names[r].split("_")[0] for r in obj}) for obj in regions]


def contacts_opposition(objects, points) -> np.ndarray:
    """:func:`opposition` (rounded to 4 decimals, as the PyBullet one) of each object's outward normals at its contact
    points: ``objects`` a :class:`components.synthesis.SceneObjects`, ``points`` (B, n_obj, C, 3) world points (any
    array-like) -> (B, n_obj)."""
    import torch

    pts = torch.as_tensor(np.asarray(points, dtype=np.float64), dtype=objects.positions.dtype)
    out = np.empty(pts.shape[:2])
    with torch.no_grad():
        for j in range(objects.n_objects):
            normals = objects.object_sdf_and_normal(j, pts[:, j])[1].double().numpy()  # (B, C, 3)
            out[:, j] = [round(opposition(n), 4) for n in normals]
    return out


def chosen_contact_opposition(frame, hand, library) -> np.ndarray | None:
    """:func:`contacts_opposition` of every row's chosen contacts (the ``contacts`` column: n_obj * C candidate
    indices, object-major) at its stored pose, (len(frame), n_obj) for rows of one object count; None without that
    column.  One batched FK per scene (:func:`benchmarks.grasp_tables.scene_batches`)."""
    if "contacts" not in frame or frame["contacts"].isna().any():
        return None
    import torch

    out = None
    for rows, objects, p, R, q in scene_batches(frame, hand, library):
        with torch.no_grad():
            points, _ = hand.contact_candidates_and_normals(p, R, q)  # (B, K, 3)
        index = np.stack(frame["contacts"].iloc[rows].to_numpy()).astype(np.int64).reshape(len(rows), objects.n_objects, -1)
        chosen = points.double().numpy()[np.arange(len(rows))[:, None, None], index]  # (B, n_obj, C, 3)
        if out is None:
            out = np.empty((len(frame), objects.n_objects))
        out[rows] = contacts_opposition(objects, chosen)
    return out


def by_contact_finger(episodes: list[dict], objects: list[dict]) -> dict:
    """Per finger of the chosen contacts: objects using it and their lift rate against the others', and the success
    rate of episodes where some object uses it against the others' (module docstring)."""
    rows = [o for o in objects if "contact_fingers" in o]
    by_episode: dict[tuple, list[dict]] = {}
    for o in rows:
        by_episode.setdefault((o["combination"], o["pose"], o["trial"]), []).append(o)
    out = {}
    for finger in sorted({f for o in rows for f in o["contact_fingers"]}):
        uses = [finger in o["contact_fingers"] for o in rows]
        ep = [(e["success"], any(finger in o["contact_fingers"] for o in by_episode[key]))
              for e in episodes if (key := (e["combination"], e["pose"], e["trial"])) in by_episode]
        out[finger] = {"objects_with": int(sum(uses)),
                       "lifted_with": _rate([o["lifted"] for o, u in zip(rows, uses) if u]),
                       "lifted_without": _rate([o["lifted"] for o, u in zip(rows, uses) if not u]),
                       "episodes_with": int(sum(u for _, u in ep)),
                       "success_with": _rate([s for s, u in ep if u]),
                       "success_without": _rate([s for s, u in ep if not u])}
    return out


def by_q1_threshold(episodes: list[dict], objects: list[dict], thresholds: Sequence[float]) -> list[dict]:
    """For each threshold t: the poses whose grasp's stored Q1 is at least t, their episodes and success rate
    (what ``synthesis.min_q1`` would keep, and how well it lifts).  Empty when the table has no Q1."""
    q1 = {(o["combination"], o["pose"]): o["q1"] for o in objects if o.get("q1") is not None}
    if not q1:
        return []
    rows = []
    for t in thresholds:
        kept = [e["success"] for e in episodes if q1.get((e["combination"], e["pose"]), -np.inf) >= t]
        rows.append({"min_q1": float(t), "poses": sum(1 for v in q1.values() if v >= t), "episodes": len(kept),
                     "success": _rate(kept)})
    return rows


def by_contact_opposition(episodes: list[dict], by_episode: dict[tuple, list[dict]], opposed_above: float) -> dict:
    """The share of episodes whose every object has its chosen contacts opposed (``contact_opposition`` above
    ``opposed_above``), and the success rate of those episodes and of the others; {} when the objects lack it."""
    flags, success = [], []
    for e in episodes:
        mine = by_episode.get((e["combination"], e["pose"], e["trial"]), [])
        if not mine or any("contact_opposition" not in o for o in mine):
            continue
        flags.append(all(o["contact_opposition"] > opposed_above for o in mine))
        success.append(e["success"])
    if not flags:
        return {}
    return {"episodes_every_object_contacts_opposed": _rate(flags),
            "success_if_every_object_contacts_opposed": _rate([s for s, f in zip(success, flags) if f]),
            "success_if_not_every_object_contacts_opposed": _rate([s for s, f in zip(success, flags) if not f])}


def _rate(flags) -> float | None:
    return round(float(np.mean(flags)), 4) if len(flags) else None


def summarise(episodes: list[dict], objects: list[dict], opposed_above: float,
              q1_thresholds: Sequence[float] = ()) -> dict:
    """Outcome counts, lift rates split by opposition at the pre-grasp, what the closure did (module docstring),
    and the success of the poses above each of ``q1_thresholds`` (:func:`by_q1_threshold`)."""
    lifted = [o["lifted"] for o in objects]
    opposed = [o["pregrasp"]["opposition"] > opposed_above for o in objects]
    kept = [o["after_closure"]["opposition"] > opposed_above for o in objects]
    by_episode: dict[tuple, list[dict]] = {}
    for o in objects:
        by_episode.setdefault((o["combination"], o["pose"], o["trial"]), []).append(o)
    every_opposed, every_kept = [], []
    for e in episodes:
        mine = by_episode.get((e["combination"], e["pose"], e["trial"]), [])
        every_opposed.append(all(o["pregrasp"]["opposition"] > opposed_above for o in mine))
        every_kept.append(all(o["after_closure"]["opposition"] > opposed_above for o in mine))
    success = [e["success"] for e in episodes]
    return {
        "episodes": len(episodes), "success": _rate(success),
        "outcome": {"all_lifted": sum(e["objects_lifted"] == e["n_objects"] for e in episodes),
                    "some_lifted": sum(0 < e["objects_lifted"] < e["n_objects"] for e in episodes),
                    "none_lifted": sum(e["objects_lifted"] == 0 for e in episodes)},
        "objects": len(objects), "objects_lifted": _rate(lifted),
        "pregrasp_opposed": _rate(opposed),
        "lifted_if_pregrasp_opposed": _rate([l for l, o in zip(lifted, opposed) if o]),
        "lifted_if_not_pregrasp_opposed": _rate([l for l, o in zip(lifted, opposed) if not o]),
        "episodes_every_object_opposed": _rate(every_opposed),
        "success_if_every_object_opposed": _rate([s for s, o in zip(success, every_opposed) if o]),
        "success_otherwise": _rate([s for s, o in zip(success, every_opposed) if not o]),
        "episodes_every_object_opposed_after_closure": _rate(every_kept),
        "success_if_every_object_opposed_after_closure": _rate([s for s, k in zip(success, every_kept) if k]),
        "pregrasp_links_median": float(np.median([o["pregrasp"]["links"] for o in objects])) if objects else None,
        "after_closure_opposed": _rate(kept),
        "after_closure_links_median": float(np.median([o["after_closure"]["links"] for o in objects])) if objects else None,
        "after_closure_no_contact": _rate([o["after_closure"]["normal_force_n"] == 0.0 for o in objects
                                           if "normal_force_n" in o["after_closure"]]),
        "closure_moved_mm_median": (round(float(np.median([o["closure_moved_mm"] for o in objects])), 2)
                                    if objects else None),
        **by_contact_opposition(episodes, by_episode, opposed_above),
        "by_contact_finger": by_contact_finger(episodes, objects),
        "by_q1_threshold": by_q1_threshold(episodes, objects, q1_thresholds),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.lift_failures", description=__doc__.split("\n\n")[0])
    add_source_args(parser)
    add_lift_args(parser, max_poses=5, trials=2, controller="squeeze")
    parser.add_argument("--near-mm", type=float, default=5.0,
                        help="a hand link this close to an object (mm) touches it at the pre-grasp (default 5)")
    parser.add_argument("--q1-thresholds", type=float, nargs="+", default=[0.0, 0.05, 0.1, 0.15, 0.2, 0.25],
                        help="the summary's by_q1_threshold: success of the poses whose stored Q1 is at least each")
    parser.add_argument("--opposed-above", type=float, default=0.5,
                        help="an object is opposed when its contact normals' opposition exceeds this (default 0.5)")
    parser.add_argument("--json", type=Path, required=True, help="write the result here")
    args = parser.parse_args(argv)
    if (status := check_lift_args(args)) is not None:
        return status
    if not args.near_mm > 0 or not -1.0 <= args.opposed_above <= 1.0:
        print("error: --near-mm must be positive and --opposed-above within [-1, 1]", file=sys.stderr)
        return 2

    def compute() -> dict:
        cfg, grasps = resolve_source(args)
        return run(grasps, cfg, None if args.split == "all" else args.split, args.max_poses, args.trials,
                   args.controller, args.near_mm * 1e-3, args.opposed_above, args.n_objects,
                   args.q1_thresholds)

    def report(result: dict) -> None:
        for key, value in result["summary"].items():
            if key not in ("by_contact_finger", "by_q1_threshold"):
                print(f"{key:32s} {value}")
        for row in result["summary"].get("by_q1_threshold", []):
            print(f"Q1 >= {row['min_q1']:<5g} {row['poses']:5d} poses, {row['episodes']:5d} episodes, "
                  f"success {row['success']}")
        for finger, rates in result["summary"].get("by_contact_finger", {}).items():
            print(f"contact finger {finger:17s} {rates}")

    return finish_tool(args.json, compute, report)


if __name__ == "__main__":
    sys.exit(main())

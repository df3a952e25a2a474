"""A lift's outcome does not depend on the process that lifts it, on lifts that succeed.

The execution evaluations split their poses into lift jobs that worker processes or Ray tasks lift
(:mod:`tasks.lift_jobs`), and serve finished jobs on a rerun; both rest on one fact: a seeded trial of a pose
gives the same outcome in any process, whatever that process lifted before.  The smoke runs' tests check the
plumbing, but their pre-grasps lift nothing, so equal outcomes there are all failures.  Here the records are four
bench Syn-Pl pair pre-grasps (``tests/data/bench_pl_pairs.json``, from the bench synthesis of the fifty-second
session) that the scripted squeeze lifts in 6 of 8 trials here (1, 1, 2, 2 of 2): a successful lift is the outcome
most sensitive to the contact solver's state.
"""

from __future__ import annotations

import multiprocessing
from pathlib import Path

import pytest

DATA = Path(__file__).parent / "data" / "bench_pl_pairs.json"
TRIALS = 2


@pytest.fixture(scope="module")
def factory(tmp_path_factory):
    from components.execution.factory import LiftEnvFactory
    from components.execution.pointnet import PointNetConfig, PointNetEncoder, save_encoder
    from components.hand import HandModel
    from flows.config import load_config
    from tasks.preflight import cache_dir

    root = tmp_path_factory.mktemp("determinism")
    cfg = load_config("bench", workdir=root)
    encoder = PointNetConfig()  # the squeeze does not read the observations: an untrained encoder will do
    save_encoder(root / "encoder.pt", PointNetEncoder(encoder), encoder)
    urdf = HandModel(cfg.hand).export_urdf(root / "hand.urdf")
    return cfg, LiftEnvFactory(hand_cfg=cfg.hand.model_dump(mode="json"), objects_cfg=cfg.objects.model_dump(mode="json"),
                               objects_cache=str(cache_dir(cfg.run.workdir)), urdf=str(urdf), records=str(DATA),
                               lift_cfg=cfg.lift.model_dump(mode="json"), encoder=str(root / "encoder.pt"))


def squeeze_outcomes(factory, stage, poses: list[int], keys: list[int]) -> list[int]:
    """Successes per pose of the bench profile's scripted squeeze (module level: a spawned worker runs it)."""
    from components.execution.evaluation import evaluate_lift
    from components.hand import HandConfig, HandModel
    from tasks.specialists import squeeze_lift

    env = factory()
    try:
        joints = HandModel(HandConfig(**factory.hand_cfg)).actuated_joint_names
        result = evaluate_lift(env, squeeze_lift(stage, joints), trials=TRIALS, seed=stage.eval_seed, poses=poses,
                               seed_keys=keys)
        return list(result.successes_per_pose)
    finally:
        env.close()


def test_a_seeded_lift_has_the_same_outcome_in_a_spawned_worker_and_after_other_lifts(factory):
    from components.execution.records import load_records
    from flows.evaluate_execution import pose_key

    cfg, make_env = factory
    records = load_records(DATA)
    keys = [pose_key(record, i) for i, record in enumerate(records)]
    every = list(range(len(records)))
    here = squeeze_outcomes(make_env, cfg.specialists, every, keys)
    assert sum(here) > 0, "the fixture's pre-grasps should lift in some trials (else this checks nothing)"
    with multiprocessing.get_context("spawn").Pool(1) as pool:
        # in another process, in reverse order, each pose after the other lifts (a job's poses after another job's)
        there = pool.apply(squeeze_outcomes, (make_env, cfg.specialists, every[::-1], keys[::-1]))[::-1]
    assert there == here
    alone = [squeeze_outcomes(make_env, cfg.specialists, [i], [keys[i]])[0] for i in (len(records) - 1, 0)]
    assert alone == [here[-1], here[0]]

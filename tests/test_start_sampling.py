"""Learnability start sampling (components/execution/start_sampling.py): the score against its formula, the draw
against its probabilities, and the env counting training episodes only."""

from pathlib import Path

import numpy as np
import pytest

from components.execution import GraspRecord, LiftEnv, LiftEnvConfig
from components.execution.cameras import CameraConfig, preview_hand_pose
from components.execution.pointnet import PointNetConfig, PointNetEncoder
from components.execution.start_sampling import FileLock, LearnabilitySampler
from components.objects import Placement, Scene

IDENTITY = (0.0, 0.0, 0.0, 1.0)


def test_an_untried_sampler_is_uniform_and_power_zero_stays_uniform():
    sampler = LearnabilitySampler(4, prior=0.5, power=2.0, uniform_mix=0.2)
    np.testing.assert_allclose(sampler.probabilities(), 0.25)
    flat = LearnabilitySampler(3, prior=0.5, power=0.0, uniform_mix=0.0)
    for index, success in ((0, True), (0, True), (1, False), (2, True), (2, False)):
        flat.update(index, success)
    np.testing.assert_allclose(flat.probabilities(), 1.0 / 3.0)


def test_scores_follow_the_beta_posterior_formula():
    sampler = LearnabilitySampler(3, prior=0.5, power=2.0, uniform_mix=0.0)
    for _ in range(6):
        sampler.update(0, False)  # never lifted in 6: p = 0.5 / 7
    for success in (True, False, True, False, True, False):
        sampler.update(1, success)  # even: p = 3.5 / 7 = 0.5
    for _ in range(6):
        sampler.update(2, True)  # always lifted: p = 6.5 / 7
    p = np.array([0.5 / 7.0, 0.5, 6.5 / 7.0])
    np.testing.assert_allclose(sampler.success_estimates(), p)
    scores = (4.0 * p * (1.0 - p)) ** 2
    np.testing.assert_allclose(sampler.scores(), scores)
    np.testing.assert_allclose(sampler.probabilities(), scores / scores.sum())
    assert sampler.scores()[1] == pytest.approx(1.0)
    assert 14.0 < sampler.scores()[1] / sampler.scores()[0] < 14.5  # the config's "1/14 as often"
    np.testing.assert_allclose(sampler.scores()[0], sampler.scores()[2])  # never and always alike


def test_the_uniform_share_keeps_every_record_and_draws_match_the_probabilities():
    sampler = LearnabilitySampler(3, prior=0.5, power=4.0, uniform_mix=0.3)
    for _ in range(50):
        sampler.update(0, False)
        sampler.update(2, True)
    probabilities = sampler.probabilities()
    assert probabilities.sum() == pytest.approx(1.0)
    assert probabilities.min() >= 0.3 / 3.0 - 1e-12
    rng = np.random.default_rng(0)
    counts = np.bincount([sampler.draw(rng) for _ in range(20000)], minlength=3) / 20000.0
    np.testing.assert_allclose(counts, probabilities, atol=0.015)


@pytest.mark.parametrize("kwargs", [dict(prior=0.0, power=1.0, uniform_mix=0.1),
                                    dict(prior=0.5, power=-1.0, uniform_mix=0.1),
                                    dict(prior=0.5, power=1.0, uniform_mix=1.5)])
def test_bad_sampler_settings_are_refused(kwargs):
    with pytest.raises(ValueError):
        LearnabilitySampler(2, **kwargs)


def test_bad_config_values_are_refused():
    with pytest.raises(ValueError):
        LiftEnvConfig(start_sampling="prioritised")
    with pytest.raises(ValueError):
        LiftEnvConfig(learnability_uniform_mix=2.0)


def test_the_env_counts_its_training_episodes_per_record_and_not_forced_ones(hand, library, tmp_path):
    records = []
    for y in (-0.03, -0.02):  # two resting scenes, an open hand above each: every short episode fails
        scene = Scene(objects=(Placement("cube", (0.0, y, 0.02), IDENTITY),
                               Placement("sphere", (0.0, y + 0.065, 0.025), IDENTITY)))
        p, R, q = preview_hand_pose(hand, scene, CameraConfig(), library)
        records.append(GraspRecord(scene=scene, p=p, R=R, q=q.astype(np.float64)))
    cfg = LiftEnvConfig(start_sampling="learnability", closure_steps=0, max_steps=2)
    encoder = PointNetEncoder(PointNetConfig()).eval()
    env = LiftEnv(hand, library, hand.export_urdf(tmp_path), records, cfg, encoder, seed=1)
    try:
        assert env.sampler is not None
        for episode in range(6):
            env.rollout(cfg.max_steps, break_when_any_done=True)  # resets, draws a record, runs it to the end
            assert env.sampler.episodes.sum() == episode + 1
            assert env.sampler.episodes[env._current] >= 1
        assert env.sampler.episodes.sum() == 6 and env.sampler.successes.sum() == 0
        env.set_next_record(0, trial_seed=5)  # an evaluation trial: not counted
        env.rollout(cfg.max_steps, break_when_any_done=True)
        assert env.sampler.episodes.sum() == 6
    finally:
        env.close()
    uniform = LiftEnv(hand, library, hand.export_urdf(tmp_path / "u"), records, LiftEnvConfig(closure_steps=0),
                      encoder)
    try:
        assert uniform.sampler is None
    finally:
        uniform.close()


def test_the_sampler_counts_into_a_given_array_and_refuses_a_wrong_one():
    counts = np.zeros((2, 2), dtype=np.int64)
    sampler = LearnabilitySampler(2, prior=0.5, power=2.0, uniform_mix=0.2, counts=counts)
    sampler.update(1, True)
    sampler.update(1, False)
    assert counts.tolist() == [[0, 0], [2, 1]]
    with pytest.raises(ValueError, match="expected"):
        LearnabilitySampler(3, prior=0.5, power=2.0, uniform_mix=0.2, counts=counts)


#: A separate interpreter that counts n episodes of record 0 into a counts file under its lock, starting at a given
#: time so that the two counters overlap.
COUNTER = """
import sys, time
import numpy as np
from components.execution.start_sampling import FileLock, LearnabilitySampler
path, n, start_at = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
counts = np.memmap(path, dtype=np.int64, mode="r+", shape=(1, 2))
sampler = LearnabilitySampler(1, prior=0.5, power=2.0, uniform_mix=0.2, counts=counts, lock=FileLock(path))
while time.time() < start_at:
    pass
for i in range(n):
    sampler.update(0, i % 2 == 0)
"""


def test_workers_counting_into_one_file_under_its_lock_lose_no_count(tmp_path):
    """Two processes that end episodes at the same moments on one memory-mapped file: the lock makes every
    read-increment-write whole, so no count is lost (the CI run of stop 46 lost one without it; without the lock
    this test loses ~7 % of the counts)."""
    import subprocess
    import sys
    import time

    from components.execution.factory import open_start_counts

    path = tmp_path / "counts.i64"
    open_start_counts(path, 1)
    n = 20_000
    start_at = time.time() + 3.0  # both interpreters are up by then
    workers = [subprocess.Popen([sys.executable, "-c", COUNTER, str(path), str(n), str(start_at)],
                                cwd=Path(__file__).resolve().parents[1], stderr=subprocess.PIPE, text=True)
               for _ in range(2)]
    for worker in workers:
        _, err = worker.communicate(timeout=300)
        assert worker.returncode == 0, err
    assert open_start_counts(path).tolist() == [[2 * n, n]]


def test_a_file_lock_pickles_as_its_path(tmp_path):
    import pickle

    path = tmp_path / "counts.i64"
    path.write_bytes(bytes(16))
    lock = FileLock(str(path))
    with lock():
        pass
    clone = pickle.loads(pickle.dumps(lock))
    assert clone.path == str(path) and clone._fd is None


def test_start_counts_summary_sorts_records_by_outcome(tmp_path):
    import json

    from tasks.specialists import write_start_counts

    counts = np.array([[0, 0], [4, 0], [3, 3], [5, 2], [8, 1]], dtype=np.int64)
    path, metrics = write_start_counts(tmp_path / "start_counts.json", counts)
    assert (metrics["start_records_untried"], metrics["start_records_never_lifted"],
            metrics["start_records_always_lifted"], metrics["start_records_mixed"]) == (1, 1, 1, 2)
    assert metrics["start_episode_share_mixed"] == pytest.approx(13 / 20, abs=1e-4)
    assert json.loads(path.read_text())["records"][3] == [5, 2]

"""Population resampling of the MALA chain (``resample_at``): who is copied, what is copied, and the stage's
bookkeeping of lineages."""

import math

import pytest
import torch

from components.errors import MultigraspError
from components.hand import HandConfig, HandModel
from components.objects import ObjectLibrary, ObjectsConfig, Placement, Scene
from components.synthesis import Annealer, GraspProblem, SceneObjects, SynthesisConfig, initial_poses, synthesize
from components.synthesis.optimizer import resample_sources, resample_steps_of, run_mala

IDENTITY = (0.0, 0.0, 0.0, 1.0)
SPHERE = Scene(objects=(Placement("sphere", (0.0, 0.0, 0.025), IDENTITY),))


@pytest.fixture(scope="module")
def hand():
    return HandModel(HandConfig())


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    return ObjectLibrary(ObjectsConfig(train=["sphere"], ood=[]), tmp_path_factory.getbasetemp() / "objects-cache")


def test_the_worst_half_takes_the_best_halfs_states_best_first():
    score = torch.tensor([3.0, 1.0, 2.0, 0.0, 5.0, 4.0])
    # ranked: 3 (0.0), 1 (1.0), 2 (2.0) survive; 0 (3.0), 5 (4.0), 4 (5.0) are replaced in that order
    assert resample_sources(score, 0.5).tolist() == [3, 1, 2, 3, 2, 1]


def test_non_finite_scores_are_replaced_first_and_large_fractions_cycle_over_the_survivors():
    score = torch.tensor([float("nan"), 1.0, float("inf"), 0.0])
    source = resample_sources(score, 0.5)
    assert source.tolist() == [3, 1, 1, 3]
    # 3 of 4 replaced: the one survivor is copied three times
    assert resample_sources(torch.tensor([2.0, 0.0, 1.0, 3.0]), 0.75).tolist() == [1, 1, 1, 1]
    # each survivor at most ceil(k / (B - k)) times
    source = resample_sources(torch.arange(10, dtype=torch.float64), 0.6)
    counts = torch.bincount(source, minlength=10)
    assert counts[:4].tolist() == [3, 3, 2, 2] and counts[4:].sum() == 0
    assert counts.max() <= 1 + math.ceil(6 / 4)


def test_a_fraction_that_replaces_nobody_keeps_every_row():
    assert resample_sources(torch.tensor([1.0, 0.0, 2.0]), 0.2).tolist() == [0, 1, 2]


def test_resample_copies_the_whole_chain_state_and_the_ancestry(hand, library):
    cfg = SynthesisConfig(batch_size=6, rmsprop_per_row=True)
    problem = GraspProblem.build(hand, SceneObjects(library, SPHERE), cfg)
    x, contacts = initial_poses(problem, torch.Generator().manual_seed(0))
    annealer = Annealer(problem, x, contacts, torch.Generator().manual_seed(1))
    state = annealer.state
    before = {"x": state.x.clone(), "contacts": state.contacts.clone(), "energy": state.energy.clone(),
              "grad": state.grad.clone(), "fc": state.terms["fc"].clone(), "ema": annealer.grad_sq_ema.clone()}
    source = resample_sources(state.energy, 0.5)
    annealer.resample(source)
    assert torch.equal(state.x, before["x"][source]) and torch.equal(state.contacts, before["contacts"][source])
    assert torch.equal(state.energy, before["energy"][source]) and torch.equal(state.grad, before["grad"][source])
    assert torch.equal(state.terms["fc"], before["fc"][source])
    assert torch.equal(annealer.grad_sq_ema, before["ema"][source])
    assert torch.equal(state.ancestor, source)
    # the rows kept are the lowest-energy half
    assert set(source.tolist()) == set(torch.argsort(before["energy"])[:3].tolist())


def test_run_mala_resamples_at_the_configured_steps_and_synthesize_reports_lineages(hand, library):
    cfg = SynthesisConfig(batch_size=8, mala_steps=20, refine_steps=2, resample_at=[0.25, 0.5])
    assert resample_steps_of(cfg) == {5, 10}
    problem = GraspProblem.build(hand, SceneObjects(library, SPHERE), cfg)
    x, contacts = initial_poses(problem, torch.Generator().manual_seed(0))
    state, stats = run_mala(problem, x, contacts, torch.Generator().manual_seed(1))
    assert stats["resampled_rows"] == 8  # 4 rows at each of the two steps
    assert len(set(state.ancestor.tolist())) <= 4  # half the lineages survive the first resampling, at most
    result = synthesize(hand, library, SPHERE, cfg, torch.Generator().manual_seed(0))
    assert result.lineage is not None and result.to_numpy()["lineage"].shape == (8,)
    assert result.stats["lineages_accepted"] == len(set(result.lineage[result.accepted].tolist()))
    # without resampling every row is its own lineage
    plain = synthesize(hand, library, SPHERE, cfg.model_copy(update={"resample_at": []}),
                       torch.Generator().manual_seed(0))
    assert plain.lineage.tolist() == list(range(8)) and plain.stats["resampled_rows"] == 0


def test_the_smooth_q1_enters_the_score_only_when_asked(hand, library):
    cfg = SynthesisConfig(batch_size=4)
    problem = GraspProblem.build(hand, SceneObjects(library, SPHERE), cfg)
    x, contacts = initial_poses(problem, torch.Generator().manual_seed(0))
    plain = Annealer(problem, x, contacts, torch.Generator().manual_seed(1))
    assert torch.equal(plain.resample_score(), plain.state.energy)
    problem_q1 = GraspProblem.build(hand, SceneObjects(library, SPHERE), cfg.model_copy(update={"resample_w_q1": 10.0}))
    with_q1 = Annealer(problem_q1, x, contacts, torch.Generator().manual_seed(1))
    extra = with_q1.resample_score() - with_q1.state.energy
    # the initial poses grasp nothing, so Q1~ is below its target and the hinge adds to every score
    assert torch.all(extra > 0) and torch.all(extra <= 10.0 * (cfg.q1_target + 1.1))


@pytest.mark.parametrize("fractions", [[1.0], [0.0], [0.5, 1.2]])
def test_resample_fractions_outside_the_chain_are_rejected_with_a_clear_error(fractions):
    with pytest.raises(ValueError, match="resample_at"):
        SynthesisConfig(resample_at=fractions)


def test_a_bad_resample_fraction_from_the_cli_is_one_line(tmp_path):
    from flows.config import load_config

    with pytest.raises(MultigraspError, match="resample_at"):
        load_config("smoke", sets=["synthesis.optimizer.resample_at=[1.0]"])


def test_jitter_moves_only_the_copies_and_keeps_their_energy_current(hand, library):
    from components.synthesis import energy_and_grad
    from components.synthesis.pose import JOINTS, ROTATION, TRANSLATION

    cfg = SynthesisConfig(batch_size=6, resample_jitter_translation_m=0.004, resample_jitter_joints_rad=0.05)
    problem = GraspProblem.build(hand, SceneObjects(library, SPHERE), cfg)
    x, contacts = initial_poses(problem, torch.Generator().manual_seed(0))
    annealer = Annealer(problem, x, contacts, torch.Generator().manual_seed(1))
    before = annealer.state.x.clone()
    source = resample_sources(annealer.state.energy, 0.5)
    annealer.resample(source)
    moved = annealer.state.x - before[source]
    copies = source != torch.arange(6)
    assert torch.all(moved[~copies] == 0)
    assert torch.all(moved[copies][:, TRANSLATION].abs().amax(-1) > 0)
    assert torch.all(moved[copies][:, JOINTS].abs().amax(-1) > 0)
    assert torch.all(moved[:, ROTATION] == 0)
    energy, _, _ = energy_and_grad(problem, annealer.state.x, annealer.state.contacts)
    assert torch.allclose(annealer.state.energy, energy)

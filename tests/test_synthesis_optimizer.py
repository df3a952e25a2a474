"""Synthesis optimiser: schedules, contact switching, the filter's reasons, and a short end-to-end run."""


import pytest
import torch

from components.hand import HandConfig, HandModel
from components.objects import ObjectLibrary, ObjectsConfig, Placement, Scene
from components.synthesis import (
    ACCEPTED,
    FILTER_REASONS,
    Annealer,
    GraspProblem,
    SceneObjects,
    SynthesisConfig,
    count_reasons,
    energy_and_grad,
    filter_grasps,
    initial_poses,
    step_size_at,
    switch_contacts,
    synthesize,
    temperature_at,
    unpack,
)
from components.synthesis.energy import CONTACT_INDICES, assignment_scores, nearest_contacts, region_contacts

SPHERE_RADIUS = 0.025
IDENTITY = (0.0, 0.0, 0.0, 1.0)


@pytest.fixture(scope="module")
def hand():
    return HandModel(HandConfig())


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    return ObjectLibrary(ObjectsConfig(train=["cube", "cylinder", "sphere"], ood=[]),
                         tmp_path_factory.getbasetemp() / "objects-cache")


def test_official_schedules_at_6500_steps():
    cfg = SynthesisConfig()
    assert cfg.schedule_periods() == (100, 50)
    assert step_size_at(0, cfg) == pytest.approx(0.01) and step_size_at(99, cfg) == pytest.approx(0.01)
    assert step_size_at(100, cfg) == pytest.approx(0.0095) and step_size_at(250, cfg) == pytest.approx(0.01 * 0.95 ** 2)
    assert temperature_at(49, cfg) == pytest.approx(8.0) and temperature_at(50, cfg) == pytest.approx(7.6)
    assert temperature_at(6499, cfg) == pytest.approx(8.0 * 0.95 ** 129)


def test_short_runs_compress_the_schedule_to_the_same_final_values():
    short = SynthesisConfig(mala_steps=650)
    assert short.schedule_periods() == (10, 5)
    assert temperature_at(649, short) == pytest.approx(temperature_at(6499, SynthesisConfig()))
    assert SynthesisConfig(mala_steps=650, compress_schedule=False).schedule_periods() == (100, 50)


@pytest.mark.parametrize("mode", ["per_step", "per_contact"])
def test_contact_switching_keeps_contacts_distinct_and_switches_at_the_configured_rate(hand, mode):
    cfg = SynthesisConfig(contact_switch_mode=mode, contact_switch_probability=0.25)
    generator = torch.Generator().manual_seed(0)
    batch, n_obj, per_object = 4000, 2, 3
    keys = torch.rand(batch, len(hand.contact_region_of), generator=generator)
    contacts = keys.argsort(1)[:, : n_obj * per_object].reshape(batch, n_obj, per_object)
    new = switch_contacts(contacts, hand.contact_region_of, cfg, generator)
    flat = new.reshape(batch, -1)
    assert all(len(set(row.tolist())) == flat.shape[1] for row in flat)
    changed = (new != contacts).reshape(batch, -1)
    if mode == "per_step":  # one contact per object in a quarter of the rows
        rows = changed.any(1)
        assert rows.float().mean() == pytest.approx(0.25, abs=0.03)
        assert torch.all(changed[rows].reshape(-1, n_obj, per_object).sum(-1) == 1)
    else:
        assert changed.float().mean() == pytest.approx(0.25, abs=0.02)


def test_local_switches_stay_in_the_contacts_region(hand):
    cfg = SynthesisConfig(contact_switch_mode="per_contact", contact_switch_probability=1.0,
                          contact_switch_local_probability=1.0)
    contacts = torch.tensor([[[0, 20, 40], [60, 80, 100]]]).repeat(200, 1, 1)
    new = switch_contacts(contacts, hand.contact_region_of, cfg, torch.Generator().manual_seed(1))
    assert torch.all(new != contacts)
    assert torch.equal(hand.contact_region_of[new], hand.contact_region_of[contacts])


def test_filter_reports_the_first_failing_criterion_and_counts_them():
    cfg = SynthesisConfig()
    ok = {"fc_per_object": torch.tensor([[0.1, 0.0]]), "contact_distance_max": torch.tensor([0.001]),
          "contact_distance_per_object": torch.tensor([[0.001, 0.001]]),
          "penetration_depth_max": torch.tensor([0.001]), "prior": torch.tensor([0.0])}
    rows = [dict(ok), dict(ok, fc_per_object=torch.tensor([[0.1, 0.3]])),
            dict(ok, contact_distance_max=torch.tensor([0.009]), contact_distance_per_object=torch.tensor([[0.001, 0.006]])),
            dict(ok, penetration_depth_max=torch.tensor([0.0051]), prior=torch.tensor([0.2])),
            dict(ok, prior=torch.tensor([0.11])), dict(ok, prior=torch.tensor([float("nan")]))]
    terms = {k: torch.cat([r[k] for r in rows]) for k in ok}
    accepted, reasons = filter_grasps(terms, cfg)
    assert accepted.tolist() == [True, False, False, False, False, False]
    assert reasons == [ACCEPTED, "fc", "contact_distance", "penetration", "prior", "non_finite"]
    counts = count_reasons(reasons)
    assert counts == {ACCEPTED: 1, "non_finite": 1, "fc": 1, "contact_distance": 1, "penetration": 1, "prior": 1}
    assert set(counts) == {ACCEPTED, *FILTER_REASONS}


def test_annealer_rejected_rows_keep_their_state(hand, library):
    scene = Scene(objects=(Placement("sphere", (0.0, 0.0, SPHERE_RADIUS), IDENTITY),))
    cfg = SynthesisConfig(batch_size=8, temperature=1e-12, temperature_decay=1.0)  # only downhill moves pass
    problem = GraspProblem.build(hand, SceneObjects(library, scene), cfg)
    x, contacts = initial_poses(problem, torch.Generator().manual_seed(0))
    annealer = Annealer(problem, x, contacts, torch.Generator().manual_seed(1))
    before = annealer.state.energy.clone()
    old_x, old_contacts = annealer.state.x.clone(), annealer.state.contacts.clone()
    annealer.try_step()
    accept = annealer.accept_step()
    assert torch.all(annealer.state.energy[accept] <= before[accept])
    assert torch.equal(annealer.state.x[~accept], old_x[~accept])
    assert torch.equal(annealer.state.contacts[~accept], old_contacts[~accept])
    assert torch.equal(annealer.state.energy[~accept], before[~accept])
    with pytest.raises(RuntimeError):
        annealer.accept_step()  # a proposal is used once


def test_short_synthesis_of_a_sphere_runs_end_to_end_and_lowers_the_energy(hand, library):
    scene = Scene(objects=(Placement("sphere", (0.0, 0.0, SPHERE_RADIUS), IDENTITY),))
    cfg = SynthesisConfig(batch_size=8, mala_steps=40, refine_steps=10, progress_every=10)
    problem = GraspProblem.build(hand, SceneObjects(library, scene), cfg)
    x0, contacts0 = initial_poses(problem, torch.Generator().manual_seed(0))
    initial_energy, _, _ = energy_and_grad(problem, x0, contacts0)
    calls = []
    result = synthesize(hand, library, scene, cfg, torch.Generator().manual_seed(0),
                        progress=lambda step, total, info: calls.append((info["stage"], step, total, info["eta_s"])))
    assert result.p.shape == (8, 3) and result.R.shape == (8, 3, 3) and result.q.shape == (8, 22)
    assert result.contacts.shape == (8, 1, 3) and result.contact_regions.shape == (8, 1, 3)
    assert torch.isfinite(result.energy).all()
    assert float(result.energy.mean()) < 0.8 * float(initial_energy.mean())
    assert len(result.reasons) == 8 and set(result.reasons) <= {ACCEPTED, *FILTER_REASONS}
    assert sum(result.reason_counts().values()) == 8
    assert result.accepted.sum() == result.reason_counts()[ACCEPTED]
    assert [c[:3] for c in calls] == [("mala", s, 40) for s in (10, 20, 30, 40)] + [("refine", s, 10) for s in (10,)]
    assert calls[-1][3] == 0.0
    arrays = result.to_numpy()
    assert arrays["q"].shape == (8, 22) and "term_fc" in arrays
    # the same generator seed gives the same result
    again = synthesize(hand, library, scene, cfg, torch.Generator().manual_seed(0))
    assert torch.equal(again.q, result.q) and again.reasons == result.reasons


def _fingers_distinct_per_object(contacts, finger_of):
    fingers = finger_of[contacts]  # (B, n_obj, C)
    return all(len(set(obj.tolist())) == obj.numel() for row in fingers for obj in row)


def test_initial_and_switched_contacts_of_one_object_sit_on_different_fingers(hand, library):
    scene = Scene(objects=(Placement("cube", (0.0, -0.03, 0.025), IDENTITY),
                           Placement("sphere", (0.0, 0.03, SPHERE_RADIUS), IDENTITY)))
    cfg = SynthesisConfig(batch_size=500, contact_switch_mode="per_contact", contact_switch_probability=1.0)
    problem = GraspProblem.build(hand, SceneObjects(library, scene), cfg)
    generator = torch.Generator().manual_seed(0)
    _, contacts = initial_poses(problem, generator)
    assert _fingers_distinct_per_object(contacts, problem.finger_of)
    for _ in range(3):
        contacts = switch_contacts(contacts, hand.contact_region_of, cfg, generator, finger_of=problem.finger_of)
        assert _fingers_distinct_per_object(contacts, problem.finger_of)
        flat = contacts.reshape(contacts.shape[0], -1)
        assert all(len(set(row.tolist())) == flat.shape[1] for row in flat)


def test_guided_switches_pick_candidates_in_proportion_to_their_weights(hand):
    cfg = SynthesisConfig(contact_switch_mode="per_contact", contact_switch_probability=1.0,
                          contact_switch_local_probability=0.0, contact_switch_guided_probability=1.0)
    batch, n_candidates = 4000, len(hand.contact_region_of)
    contacts = torch.tensor([[[0]]]).repeat(batch, 1, 1)
    log_weights = torch.full((batch, 1, n_candidates), -30.0)
    log_weights[:, 0, 10], log_weights[:, 0, 20] = 0.0, float(torch.log(torch.tensor(3.0)))  # odds 1 : 3
    new = switch_contacts(contacts, hand.contact_region_of, cfg, torch.Generator().manual_seed(2),
                          log_weights=log_weights)
    assert set(new.flatten().tolist()) <= {10, 20}
    assert float((new == 20).float().mean()) == pytest.approx(0.75, abs=0.03)


def _pair_problem(hand, library, **overrides):
    scene = Scene(objects=(Placement("cube", (0.0, -0.03, 0.025), IDENTITY),
                           Placement("sphere", (0.0, 0.03, SPHERE_RADIUS), IDENTITY)))
    cfg = SynthesisConfig(batch_size=16, **overrides)
    return GraspProblem.build(hand, SceneObjects(library, scene), cfg), scene


def test_region_assignment_moves_each_contact_to_its_regions_best_candidate(hand, library):
    problem, _ = _pair_problem(hand, library, contact_assignment="region")
    x, contacts = initial_poses(problem, torch.Generator().manual_seed(0))
    p, R, q = unpack(x)
    points, normals = hand.contact_candidates_and_normals(p, R, problem.effective_joints(q))
    chosen = region_contacts(problem, contacts, points, normals)
    region_of = hand.contact_region_of
    assert torch.equal(region_of[chosen], region_of[contacts])  # the switches' region is kept
    score = assignment_scores(problem, points, normals)  # (B, n_obj, K)
    for b in range(4):
        for j in range(2):
            for c in range(3):
                members = (region_of == region_of[contacts[b, j, c]]).nonzero().squeeze(-1)
                assert float(score[b, j, chosen[b, j, c]]) == pytest.approx(float(score[b, j, members].min()))
    # the energy reports the contacts it used
    _, _, terms = energy_and_grad(problem, x, contacts)
    assert torch.equal(terms[CONTACT_INDICES], chosen)


def test_nearest_assignment_takes_the_best_candidate_of_the_best_fingers(hand, library):
    problem, scene = _pair_problem(hand, library, contact_assignment="nearest")
    x, contacts = initial_poses(problem, torch.Generator().manual_seed(1))
    p, R, q = unpack(x)
    points, normals = hand.contact_candidates_and_normals(p, R, problem.effective_joints(q))
    chosen = nearest_contacts(problem, points, normals)
    assert _fingers_distinct_per_object(chosen, problem.finger_of)
    score = assignment_scores(problem, points, normals)
    finger_of = problem.finger_of
    for b in range(4):
        for j in range(2):
            per_finger = sorted(float(score[b, j, finger_of == f].min()) for f in range(int(finger_of.max()) + 1))
            assert sorted(float(score[b, j, k]) for k in chosen[b, j]) == pytest.approx(per_finger[:3])
    # the energy ignores the input contacts and the synthesis returns the ones it used
    _, _, terms = energy_and_grad(problem, x, contacts)
    assert torch.equal(terms[CONTACT_INDICES], chosen)
    result = synthesize(hand, library, scene, problem.cfg.model_copy(
        update={"batch_size": 4, "mala_steps": 4, "refine_steps": 2}), torch.Generator().manual_seed(0))
    assert _fingers_distinct_per_object(result.contacts, finger_of)
    assert torch.equal(result.contact_regions, hand.contact_region_of[result.contacts])


def test_fc_weight_ramp_levels():
    from components.synthesis.optimizer import fc_weight_at

    cfg = SynthesisConfig(mala_steps=1000, w_fc=2.0, w_fc_ramp_fraction=0.4)  # ramp over 400 steps
    assert fc_weight_at(0, cfg) == 0.0 and fc_weight_at(39, cfg) == 0.0
    assert fc_weight_at(40, cfg) == pytest.approx(0.2) and fc_weight_at(399, cfg) == pytest.approx(1.8)
    assert fc_weight_at(400, cfg) == 2.0 and fc_weight_at(999, cfg) == 2.0
    assert fc_weight_at(0, SynthesisConfig(w_fc=2.0)) == 2.0  # no ramp


def test_best_contacts_never_raise_the_contact_energy_and_keep_fingers_distinct(hand, library):
    from components.synthesis.energy import best_contacts

    problem, _ = _pair_problem(hand, library)
    x, contacts = initial_poses(problem, torch.Generator().manual_seed(0))
    p, R, q = unpack(x)
    points, normals = hand.contact_candidates_and_normals(p, R, problem.effective_joints(q))
    chosen = best_contacts(problem, points, normals, contacts)
    assert _fingers_distinct_per_object(chosen, problem.finger_of)
    flat = chosen.reshape(chosen.shape[0], -1)
    assert all(len(set(row.tolist())) == flat.shape[1] for row in flat)  # distinct across objects too

    def contact_energy(c):
        _, _, terms = energy_and_grad(problem, x, c)
        cfg = problem.cfg
        return cfg.w_fc * terms["fc"] + cfg.w_dist * terms["dist"] + cfg.w_align * terms["align"]

    before, after = contact_energy(contacts), contact_energy(chosen)
    assert torch.all(after <= before + 1e-6)
    assert float(after.mean()) < float(before.mean())  # random initial contacts are improved
    assert torch.equal(best_contacts(problem, points, normals, chosen), chosen)  # a fixed point


def test_mean_filter_reduces_each_objects_contacts_by_their_mean():
    from components.synthesis.filtering import contact_distance_for_filter

    terms = {"contact_distance_max": torch.tensor([0.012]), "contact_distance_per_object": torch.tensor([[0.004, 0.003]])}
    max_cfg = SynthesisConfig(filter_contact_distance_reduce="max")
    assert float(contact_distance_for_filter(terms, max_cfg)) == pytest.approx(0.012)
    # the default is the official reduction: each object's mean, then the worst object
    assert float(contact_distance_for_filter(terms, SynthesisConfig())) == pytest.approx(0.004)


def test_approach_stage_brings_contacts_closer_without_force_closure_and_runs_in_synthesize(hand, library):
    from components.synthesis.optimizer import approach

    scene = Scene(objects=(Placement("sphere", (0.0, 0.0, SPHERE_RADIUS), IDENTITY),))
    cfg = SynthesisConfig(batch_size=4, approach_steps=30, approach_reassign_every=10, mala_steps=5,
                          refine_steps=5, progress_every=10)
    problem = GraspProblem.build(hand, SceneObjects(library, scene), cfg)
    x0, c0 = initial_poses(problem, torch.Generator().manual_seed(0))
    _, _, t0 = energy_and_grad(problem, x0, c0)
    x, c, stats = approach(problem, x0, c0)
    _, _, t1 = energy_and_grad(problem, x, c)
    assert "approach_seconds" in stats and c.shape == c0.shape
    assert float(t1["dist"].mean()) < float(t0["dist"].mean())
    calls = []
    result = synthesize(hand, library, scene, cfg, torch.Generator().manual_seed(0),
                        progress=lambda step, total, info: calls.append((info["stage"], step, total)))
    assert calls[:3] == [("approach", s, 30) for s in (10, 20, 30)]
    assert "approach_seconds" in result.stats and torch.isfinite(result.energy).all()
    off = SynthesisConfig(batch_size=4, mala_steps=5, refine_steps=5)
    assert "approach_seconds" not in synthesize(hand, library, scene, off, torch.Generator().manual_seed(0)).stats


def test_release_step_rule_is_the_official_gradient_step(hand, library):
    """mala_step_rule 'release': x' = x - s^2/2 m g~ + s sigma xi, with the rotation gradient x10 and the joint
    gradient over the EMA of its batch-mean |g| times w(t) (85 at t = 0, 25 from 80 % of the chain on)."""
    from components.synthesis.pose import JOINTS, ROTATION, TRANSLATION

    scene = Scene(objects=(Placement("sphere", (0.0, 0.0, SPHERE_RADIUS), IDENTITY),))
    cfg = SynthesisConfig(batch_size=4, mala_steps=100, mala_step_rule="release", langevin_noise=0.0, step_size=1.0,
                          contact_switch_probability=0.0)
    problem = GraspProblem.build(hand, SceneObjects(library, scene), cfg)
    x, contacts = initial_poses(problem, torch.Generator().manual_seed(0))
    annealer = Annealer(problem, x, contacts, torch.Generator().manual_seed(1))
    g, s = annealer.state.grad, step_size_at(0, cfg)
    x_new, _ = annealer.try_step()
    step = (annealer.state.x - x_new) / (0.5 * s * s)
    assert torch.allclose(step[:, TRANSLATION], g[:, TRANSLATION], rtol=1e-4, atol=1e-5)
    assert torch.allclose(step[:, ROTATION], 10.0 * g[:, ROTATION], rtol=1e-4, atol=1e-5)
    expected = g[:, JOINTS] / (g[:, JOINTS].abs().mean(0) + cfg.rmsprop_epsilon) * 85.0
    assert torch.allclose(step[:, JOINTS], expected, rtol=1e-4, atol=1e-6)
    annealer.step = 80
    assert annealer.release_joint_weight() == pytest.approx(25.0)
    annealer.step = 40
    assert annealer.release_joint_weight() == pytest.approx(55.0)


def test_best_contacts_with_the_opposition_term_choose_more_opposed_sets(hand, library):
    """With w_opposition the reassignment's score includes E_opp, so the chosen sets oppose at least as often and
    the contact part of the energy (E_opp included) still never rises."""
    from components.synthesis.energy import best_contacts, contact_opposition_energy

    plain, _ = _pair_problem(hand, library, w_fc=20.0)
    opposed, _ = _pair_problem(hand, library, w_fc=20.0, w_opposition=50.0)
    x, contacts = initial_poses(plain, torch.Generator().manual_seed(0))
    p, R, q = unpack(x)
    points, normals = hand.contact_candidates_and_normals(p, R, plain.effective_joints(q))

    def opposition(c):  # (B,) sum over objects of E_opp of the chosen contacts (object normals)
        total = torch.zeros(c.shape[0], dtype=points.dtype)
        for j in range(c.shape[1]):
            pts = points.gather(1, c[:, j].unsqueeze(-1).expand(-1, -1, 3))
            _, n = plain.objects.object_sdf_and_normal(j, pts)
            total = total + contact_opposition_energy(n, 0.5)
        return total

    without, with_term = best_contacts(plain, points, normals, contacts), best_contacts(opposed, points, normals, contacts)
    assert float(opposition(with_term).sum()) < float(opposition(without).sum())  # seed 0: fewer one-sided sets
    _, _, before = energy_and_grad(opposed, x, contacts)
    _, _, after = energy_and_grad(opposed, x, with_term)
    score = lambda t: 20.0 * t["fc"] + opposed.cfg.w_dist * t["dist"] + opposed.cfg.w_align * t["align"] + 50.0 * t["opposition"]
    assert torch.all(score(after) <= score(before) + 1e-6)

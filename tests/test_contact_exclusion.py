"""``contact_regions_excluded``: excluded hand regions are never a chosen contact -- not in the initial draw, not
after a switch, not after a reassignment, not in a synthesised grasp -- and bad names fail in one line."""

import pytest
import torch

from components.errors import MultigraspError
from components.objects import Placement, Scene
from components.synthesis import GraspProblem, SceneObjects, SynthesisConfig, initial_poses, switch_contacts, synthesize
from components.synthesis.energy import best_contacts, nearest_contacts
from components.synthesis.pose import unpack

IDENTITY = (0.0, 0.0, 0.0, 1.0)
PAIR = Scene(objects=(Placement("cube", (0.0, -0.03, 0.025), IDENTITY),
                      Placement("sphere", (0.0, 0.03, 0.025), IDENTITY)))
PALM = ["palm", "palm_hypothenar"]


def _problem(hand, library, **overrides):
    cfg = SynthesisConfig(batch_size=64, contact_regions_excluded=PALM, **overrides)
    return GraspProblem.build(hand, SceneObjects(library, PAIR, hand.device, hand.dtype), cfg)


def _excluded(hand, contacts) -> bool:
    """Whether any contact lies in a palm region."""
    palm = [hand.region_names.index(n) for n in PALM]
    return bool(torch.isin(hand.contact_region_of[contacts], torch.tensor(palm)).any())


def test_the_mask_covers_exactly_the_excluded_regions(hand, library):
    problem = _problem(hand, library)
    allowed = problem.candidate_allowed
    palm = torch.isin(hand.contact_region_of, torch.tensor([hand.region_names.index(n) for n in PALM]))
    assert torch.equal(allowed, ~palm) and int(palm.sum()) > 0
    unmasked = GraspProblem.build(hand, SceneObjects(library, PAIR, hand.device, hand.dtype), SynthesisConfig(batch_size=4))
    assert unmasked.candidate_allowed is None


def test_initial_contacts_and_switches_never_pick_an_excluded_region(hand, library):
    problem = _problem(hand, library, contact_switch_mode="per_contact", contact_switch_probability=1.0)
    generator = torch.Generator().manual_seed(0)
    _, contacts = initial_poses(problem, generator)
    assert not _excluded(hand, contacts)
    # without the mask, the same draws do use the palm (so the check above is not vacuous)
    free = GraspProblem.build(hand, SceneObjects(library, PAIR, hand.device, hand.dtype), problem.cfg.model_copy(
        update={"contact_regions_excluded": []}))
    assert _excluded(hand, initial_poses(free, torch.Generator().manual_seed(0))[1])
    for _ in range(5):
        contacts = switch_contacts(contacts, hand.contact_region_of, problem.cfg, generator,
                                   finger_of=problem.finger_of, candidate_allowed=problem.candidate_allowed)
        assert not _excluded(hand, contacts)


def test_reassignment_and_nearest_contacts_skip_excluded_regions(hand, library):
    problem = _problem(hand, library)
    x, contacts = initial_poses(problem, torch.Generator().manual_seed(1))
    p, R, q = unpack(x)
    points, normals = hand.contact_candidates_and_normals(p, R, problem.effective_joints(q))
    assert not _excluded(hand, best_contacts(problem, points, normals, contacts))
    assert not _excluded(hand, nearest_contacts(problem, points, normals))


def test_a_synthesised_grasp_has_no_contact_in_an_excluded_region(hand, library):
    cfg = SynthesisConfig(batch_size=8, mala_steps=20, refine_steps=10, approach_steps=10, contact_assignment="region",
                          contact_reassign_every=5, contact_reassign_refine=True, contact_regions_excluded=PALM)
    result = synthesize(hand, library, PAIR, cfg, torch.Generator().manual_seed(0))
    assert not _excluded(hand, result.contacts)


def test_unknown_regions_and_too_few_fingers_fail_in_one_line(hand, library):
    with pytest.raises(MultigraspError, match=r"unknown hand region\(s\) \['thumb'\]"):
        GraspProblem.build(hand, SceneObjects(library, PAIR, hand.device, hand.dtype), SynthesisConfig(contact_regions_excluded=["thumb"]))
    fingers = [n for n in hand.region_names if not n.startswith(("ff", "mf"))]
    with pytest.raises(MultigraspError, match="leaves 2 finger"):
        GraspProblem.build(hand, SceneObjects(library, PAIR, hand.device, hand.dtype), SynthesisConfig(contact_regions_excluded=fingers))

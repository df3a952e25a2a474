"""Shadow Hand contact candidates and keypoints: counts, placement on the surface, palmar side."""

import pytest
import torch

from components.errors import MultigraspError
from components.hand import HandConfig, HandModel

POINTS_PER_REGION = 6
DTYPE = torch.float64
SURFACE_TOLERANCE = 1e-6  # m
FINGERS = ("ff", "mf", "rf", "lf", "th")


@pytest.fixture(scope="module")
def hand():
    return HandModel(HandConfig(contact_points_per_region=POINTS_PER_REGION), dtype=DTYPE)


def identity_pose(batch):
    return torch.zeros(batch, 3, dtype=DTYPE), torch.eye(3, dtype=DTYPE).expand(batch, 3, 3)


def test_region_and_keypoint_counts(hand):
    assert len(hand.region_names) == 17
    assert hand.region_names[:2] == ["palm", "palm_hypothenar"]
    segments = ("proximal", "middle", "distal")
    assert sorted(hand.region_names[2:]) == sorted(f"{f}_{s}" for f in FINGERS for s in segments)
    assert hand.contact_region_of.shape == (17 * POINTS_PER_REGION,)
    assert torch.equal(torch.bincount(hand.contact_region_of), torch.full((17,), POINTS_PER_REGION))
    p, R = identity_pose(4)
    q = hand.sample_joint_angles(4, torch.Generator().manual_seed(0))
    assert hand.contact_candidates(p, R, q).shape == (4, 17 * POINTS_PER_REGION, 3)
    assert hand.keypoints(p, R, q).shape == (4, 31, 3)
    assert len(hand.keypoint_names) == len(set(hand.keypoint_names)) == 31


def test_contact_candidates_lie_on_the_hand_surface(hand):
    p, R = identity_pose(8)
    q = hand.sample_joint_angles(8, torch.Generator().manual_seed(1))
    q[0] = hand.open_pose()
    points = hand.contact_candidates(p, R, q)
    distance = hand.signed_distance(points, p, R, q)
    # on the surface of their own geom, and not buried inside a neighbouring one at the open pose
    assert distance[0].abs().max() < SURFACE_TOLERANCE
    assert distance.max() < SURFACE_TOLERANCE


def test_tip_and_pad_keypoints_lie_on_the_distal_capsules(hand):
    p, R = identity_pose(1)
    q = hand.open_pose()[None]
    points = hand.keypoints(p, R, q)
    on_surface = [i for i, n in enumerate(hand.keypoint_names) if n.endswith(("_tip", "_pad"))]
    assert len(on_surface) == 10
    assert hand.signed_distance(points[:, on_surface], p, R, q).abs().max() < SURFACE_TOLERANCE


def test_finger_candidates_face_the_palm_side_at_the_open_pose(hand):
    """At the open pose the palm normal is -y of the palm frame; finger and palm candidates lie on that side."""
    p, R = identity_pose(1)
    q = hand.open_pose()[None]
    points = hand.contact_candidates(p, R, q)[0]  # (K, 3) palm frame
    frames = hand.forward_kinematics(q)[0]
    for region, name in enumerate(hand.region_names):
        if name.startswith("th_"):
            continue
        mask = hand.contact_region_of == region
        if name.startswith("palm"):
            assert (points[mask, 1] < 0).all(), name
        else:
            axis_y = frames[hand.link_names.index(name.replace("_", "")), 1, 3]  # the capsule axis' y
            assert (points[mask, 1] < axis_y - 1e-3).all(), name


# each segment's own flexion joint and the sign that closes it (the thumb's THJ1 range is symmetric:
# it closes in the same sense as THJ0, whose range is [-1.571, 0])
FLEXION = {f"{f}_{s}": (f"{f.upper()}J{j}", 1.0) for f in ("ff", "mf", "rf", "lf")
           for s, j in (("proximal", 2), ("middle", 1), ("distal", 0))}
FLEXION.update({"th_proximal": ("THJ3", 1.0), "th_middle": ("THJ1", -1.0), "th_distal": ("THJ0", -1.0)})
FLEXION_STEP = 0.1  # rad


@pytest.mark.parametrize("region_name", sorted(FLEXION))
def test_candidates_face_the_direction_the_segment_flexes(hand, region_name):
    """Closing a segment's own flexion joint moves the segment's far end towards its candidates' side."""
    p, R = identity_pose(2)
    q = hand.open_pose().repeat(2, 1)
    joint, sign = FLEXION[region_name]
    q[1, hand.joint_names.index(joint)] = sign * FLEXION_STEP
    link = hand.link_names.index(region_name.replace("_", ""))
    frames = hand.forward_kinematics(q)[:, link]  # (2, 4, 4)
    far_end = torch.tensor([0.0, 0.0, 0.02, 1.0], dtype=DTYPE)  # 2 cm along the segment
    motion = (frames[1] @ far_end - frames[0] @ far_end)[:3]  # (3,) palm frame
    points = hand.contact_candidates(p, R, q[:1])[0]
    region = hand.region_names.index(region_name)
    offset = points[hand.contact_region_of == region] - frames[0, :3, 3]
    axis = frames[0, :3, 2]
    radial = offset - (offset @ axis)[:, None] * axis  # away from the capsule axis
    assert (radial @ motion > 0).all()


def test_missing_data_file_is_a_one_line_error(tmp_path):
    with pytest.raises(MultigraspError, match="missing hand data file"):
        HandModel(HandConfig(assets_dir=tmp_path))


def test_unknown_config_key_is_rejected():
    with pytest.raises(Exception):
        HandConfig(contact_points=3)

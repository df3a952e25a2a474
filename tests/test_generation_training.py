"""Generator training data (palm-aligned GraspDataset from synthesis rows) and training with checkpoints,
resume, corrupt-file errors and loading."""

import math

import numpy as np
import pandas as pd
import pytest
import torch
from scipy.spatial.transform import Rotation

from components.errors import MultigraspError
from components.generation import (
    AlignedFrame,
    GeneratorConfig,
    GraspDataset,
    IKConfig,
    generate_grasps,
    load_generator,
    palm_direction,
    posed_clouds,
    train_generator,
)
from components.generation.training import build_generator

torch.set_num_threads(1)

TINY = dict(points_per_object=64, sa1_points=16, sa1_neighbours=8, sa1_widths=(16, 16), sa2_points=4,
            sa2_neighbours=8, sa2_widths=(16, 32), global_widths=(32,), model_dim=32, heads=2, blocks=1,
            time_embedding_dim=16, diffusion_steps=10, batch_size=4, train_steps=10, log_every=1,
            checkpoint_every=3, lr=1e-3, seed=3)
SCENES = [  # (names, positions)
    (["cube"], [[0.10, -0.05, 0.025]]),
    (["cube", "sphere"], [[-0.04, 0.02, 0.025], [0.04, 0.03, 0.03]]),
    (["sphere", "cylinder"], [[0.20, 0.10, 0.03], [0.26, 0.12, 0.04]]),
]


def synthesis_frame(hand, with_rejected: bool = True) -> pd.DataFrame:
    """Two grasps per scene (random palm orientations above the objects), plus one rejected row."""
    rng = np.random.default_rng(0)
    q = hand.open_pose().detach().cpu().numpy()
    rows = []
    for s, (names, positions) in enumerate(SCENES):
        positions = np.asarray(positions)
        quats = Rotation.from_euler("z", rng.uniform(-np.pi, np.pi, (len(names), 1))).as_quat()
        for g in range(2 + int(with_rejected and s == 0)):
            R = Rotation.random(random_state=int(rng.integers(1 << 30))).as_matrix()
            p = positions.mean(0) + np.array([0.0, 0.0, 0.08]) + rng.normal(0, 0.01, 3)
            rows.append({"scene_id": f"train-{s}", "split": "train", "combination": "+".join(names), "row": g,
                         "object_names": list(names), "object_positions": positions.reshape(-1).tolist(),
                         "object_quats_xyzw": quats.reshape(-1).tolist(), "p": p.tolist(),
                         "R": R.reshape(-1).tolist(), "q": (q + rng.normal(0, 0.05, 22)).tolist(),
                         "accepted": g < 2, "energy": float(rng.uniform())})
    return pd.DataFrame(rows)


@pytest.fixture(scope="module")
def frame(hand):
    return synthesis_frame(hand)


@pytest.fixture(scope="module")
def cfg():
    return GeneratorConfig(**TINY)


@pytest.fixture(scope="module")
def dataset(frame, library, hand, cfg):
    return GraspDataset.from_frame(frame, library, hand, cfg)


@pytest.fixture(scope="module")
def trained(dataset, cfg, tmp_path_factory):
    """An uninterrupted 10-step run: (result, checkpoint path, progress calls)."""
    path = tmp_path_factory.mktemp("gen-full") / "generator.pt"
    calls = []
    result = train_generator(dataset, cfg, path, progress=lambda step, total, info: calls.append((step, total, info)))
    return result, path, calls


# ============================================================================ dataset
def test_dataset_shapes_mask_and_padding(dataset, cfg):
    assert len(dataset) == 6  # the rejected row is left out
    assert dataset.scenes == 3
    x0, objects = dataset.batch(torch.arange(6))
    assert x0.shape == (6, 93) and x0.dtype == torch.float32
    assert objects.clouds.shape == (6, cfg.max_objects, cfg.points_per_object, 3)
    expected_mask = torch.tensor([[True, False, False]] * 2 + [[True, True, False]] * 4)
    assert torch.equal(objects.mask, expected_mask)
    assert float(objects.clouds[~objects.mask].abs().max()) == 0.0  # empty slots are zeros
    x_sub, obj_sub = dataset.batch([4, 1])
    assert torch.equal(x_sub, x0[[4, 1]]) and torch.equal(obj_sub.clouds, objects.clouds[[4, 1]])


def test_alignment_puts_the_palm_direction_on_plus_x_and_the_objects_centroid_at_the_origin(dataset, frame, library,
                                                                                             hand, cfg):
    direction = palm_direction(dataset.R.double())  # aligned palm direction
    horizontal = direction[:, :2].norm(dim=-1)
    assert bool((horizontal > 1e-3).all())  # random palms are not vertical
    assert torch.allclose(direction[:, 1], torch.zeros(6, dtype=torch.float64), atol=1e-6)
    assert bool((direction[:, 0] > 0).all())
    _, objects = dataset.batch(torch.arange(6))
    weights = objects.mask.double().unsqueeze(-1)
    centroid = (objects.clouds.double().mean(2) * weights).sum(1) / weights.sum(1)
    assert torch.allclose(centroid[:, :2], torch.zeros(6, 2, dtype=torch.float64), atol=1e-6)

    # x0 are the aligned keypoints; mapping them (and the clouds) back reproduces the world data
    accepted = frame[frame["accepted"]].reset_index(drop=True)
    p = torch.tensor(np.stack(accepted["p"]), dtype=hand.dtype)
    R = torch.tensor(np.stack(accepted["R"]), dtype=hand.dtype).reshape(-1, 3, 3)
    q = torch.tensor(np.stack(accepted["q"]), dtype=hand.dtype)
    aligned_kp = hand.keypoints(dataset.p.to(hand.dtype), dataset.R.to(hand.dtype), dataset.q.to(hand.dtype))
    assert torch.allclose(dataset.x0.reshape(6, 31, 3).double(), aligned_kp.double(), atol=1e-5)
    back = AlignedFrame(dataset.yaw.double(), dataset.pivot.double())
    assert torch.allclose(back.points_from_aligned(dataset.x0.reshape(6, 31, 3).double()),
                          hand.keypoints(p, R, q).double(), atol=1e-5)
    for i, row in accepted.iterrows():
        world, mask = posed_clouds(library, row["object_names"], row["object_positions"], row["object_quats_xyzw"],
                                   cfg.points_per_object, cfg.max_objects)
        restored = back.points_from_aligned(objects.clouds.double())[i]
        assert np.allclose(restored[torch.as_tensor(mask)].numpy(), world[mask], atol=1e-5)
    # the pivot is what generate_grasps computes from world clouds (heights kept: z = 0)
    assert torch.allclose(dataset.pivot[:, 2], torch.zeros(6))


def test_joint_representation_and_split_filter(frame, library, hand):
    joints = GraspDataset.from_frame(frame, library, hand, GeneratorConfig(representation="joints", **TINY))
    assert joints.x0.shape == (6, 31)
    one = GraspDataset.from_frame(frame.assign(split=["train"] * 3 + ["Pl"] * 4), library, hand,
                                  GeneratorConfig(**TINY), splits=["train"])
    assert len(one) == 2


def test_empty_or_all_rejected_frames_are_one_line_errors(frame, library, hand, cfg):
    for empty in (frame.iloc[:0], frame.assign(accepted=False)):
        with pytest.raises(MultigraspError, match="no grasps to train on; the synthesis stage accepted none") as info:
            GraspDataset.from_frame(empty, library, hand, cfg)
        assert "\n" not in str(info.value)


def test_too_many_objects_is_a_one_line_error(frame, library, hand):
    with pytest.raises(MultigraspError, match="max_objects"):
        GraspDataset.from_frame(frame, library, hand, GeneratorConfig(**{**TINY, "max_objects": 1}))


# ============================================================================ training
def test_training_gives_finite_losses_a_checkpoint_and_progress(trained):
    result, path, calls = trained
    assert path.exists()
    assert result.resumed_from == 0
    assert [row["step"] for row in result.history] == list(range(1, 11))
    assert all(math.isfinite(row["loss"]) for row in result.history)
    assert [c[0] for c in calls] == list(range(1, 11)) and all(c[1] == 10 for c in calls)
    assert not result.generator.training
    fresh = build_generator(result.generator.cfg).state_dict()  # the same seeded initialisation
    assert not torch.equal(fresh["denoiser.token_out.weight"], result.generator.state_dict()["denoiser.token_out.weight"])


def test_resume_from_an_interrupted_run_matches_an_uninterrupted_one(dataset, cfg, trained, tmp_path):
    full, _, _ = trained
    path = tmp_path / "generator.pt"
    half = train_generator(dataset, cfg.model_copy(update={"train_steps": 5}), path)
    assert half.resumed_from == 0 and len(half.history) == 5
    resumed = train_generator(dataset, cfg, path)
    assert resumed.resumed_from == 5
    assert [row["step"] for row in resumed.history] == list(range(1, 11))
    assert [r["loss"] for r in resumed.history] == [r["loss"] for r in full.history]
    full_state, resumed_state = full.generator.state_dict(), resumed.generator.state_dict()
    assert all(torch.equal(full_state[k], resumed_state[k]) for k in full_state)
    again = train_generator(dataset, cfg, path)  # finished: returns at once
    assert again.resumed_from == 10 and len(again.history) == 10


def test_extendable_step_accepts_a_shorter_training_of_the_same_model_only(dataset, cfg, tmp_path):
    from components.generation import extendable_step

    path = tmp_path / "generator.pt"
    train_generator(dataset, cfg.model_copy(update={"train_steps": 3}), path)
    assert extendable_step(path, cfg) == 3  # cfg trains 10 steps: continue from 3
    assert extendable_step(path, cfg.model_copy(update={"train_steps": 3, "log_every": 7})) == 3
    assert extendable_step(path, cfg.model_copy(update={"train_steps": 2})) is None  # longer than asked
    assert extendable_step(path, cfg.model_copy(update={"lr": cfg.lr / 2})) is None  # another training
    assert extendable_step(tmp_path / "missing.pt", cfg) is None
    (tmp_path / "bad.pt").write_bytes(b"not a checkpoint")
    assert extendable_step(tmp_path / "bad.pt", cfg) is None


def test_corrupt_or_foreign_or_mismatched_checkpoints_are_one_line_errors(dataset, cfg, trained, tmp_path):
    bad = tmp_path / "generator.pt"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(MultigraspError, match="corrupt.*delete it") as info:
        train_generator(dataset, cfg, bad)
    assert str(bad) in str(info.value) and "\n" not in str(info.value)
    torch.save({"weights": torch.zeros(2)}, bad)
    with pytest.raises(MultigraspError, match="not a grasp-generator checkpoint"):
        load_generator(bad)
    _, path, _ = trained
    with pytest.raises(MultigraspError, match="different generator config.*model_dim"):
        train_generator(dataset, cfg.model_copy(update={"model_dim": 64}), path)


def test_load_generator_samples_and_generates(dataset, cfg, trained, tmp_path, hand):
    with pytest.raises(MultigraspError, match="multigrasp run --until train-generator"):
        load_generator(tmp_path / "missing.pt")
    result, path, _ = trained
    model = load_generator(path)
    assert not model.training
    assert torch.equal(model.standardizer.mean, dataset.x0.mean(0))
    state = result.generator.state_dict()
    assert all(torch.equal(v, state[k]) for k, v in model.state_dict().items())
    _, objects = dataset.batch([0, 3])
    x = model.sample(objects, per_scene=2, generator=torch.Generator().manual_seed(0))
    assert x.shape == (4, 93) and bool(torch.isfinite(x).all())
    # generation in the world from the loaded model (a few IK steps only)
    scenes = dataset.scene_index[[0, 3]]
    world = (dataset.scene_clouds[scenes] + dataset.pivot[[0, 3], None, None, :]) * dataset.scene_mask[scenes][..., None, None]
    p, R, q = generate_grasps(model, hand, world, torch.tensor([0.0, 1.0]), IKConfig(steps=3, restarts=1),
                              mask=objects.mask, per_scene=2, generator=torch.Generator().manual_seed(0))
    assert p.shape == (4, 3) and R.shape == (4, 3, 3) and q.shape == (4, 22)
    assert bool(torch.isfinite(p).all())


def test_a_crash_between_checkpoints_resumes_from_the_last_one_with_the_same_result(dataset, cfg, tmp_path):
    cfg = cfg.model_copy(update={"train_steps": 7, "log_every": 2, "checkpoint_every": 3})
    full = train_generator(dataset, cfg, tmp_path / "full.pt")
    path = tmp_path / "crash.pt"

    def crash(step, total, info):
        if step == 4:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train_generator(dataset, cfg, path, progress=crash)
    resumed = train_generator(dataset, cfg, path)
    assert resumed.resumed_from == 3
    assert [r["step"] for r in resumed.history] == [2, 4, 6, 7]
    assert [r["loss"] for r in resumed.history] == [r["loss"] for r in full.history]
    full_state, resumed_state = full.generator.state_dict(), resumed.generator.state_dict()
    assert all(torch.equal(full_state[k], resumed_state[k]) for k in full_state)


def test_dataset_reads_the_parquet_round_trip(frame, library, hand, cfg, dataset, tmp_path):
    frame.to_parquet(tmp_path / "grasps.parquet")
    again = GraspDataset.from_frame(pd.read_parquet(tmp_path / "grasps.parquet"), library, hand, cfg)
    assert torch.equal(again.x0, dataset.x0) and torch.equal(again.scene_clouds, dataset.scene_clouds)

"""PointNet encoder / autoencoder pretraining (components.execution.pointnet), with tiny configs."""

import numpy as np
import pytest
import torch

from components.errors import MultigraspError
from components.execution.pointnet import (PointNetConfig, PointNetEncoder, chamfer_distance, load_encoder,
                                           pretrain_pointnet, save_encoder)

TINY = PointNetConfig(feature_dim=32, encoder_widths=(16, 32), decoder_widths=(64,), points_per_cloud=64,
                      steps=100, batch_size=8, lr=3e-3, log_every=10, jitter_std_m=0.001)


def shape_clouds(count: int = 16, points: int = 128, seed: int = 0) -> torch.Tensor:
    """Spheres and boxes of different sizes (m) at different offsets from the palm: (count, points, 3)."""
    g = torch.Generator().manual_seed(seed)
    clouds = []
    for i in range(count):
        size = 0.02 + 0.06 * i / count
        offset = torch.tensor([0.0, 0.0, 0.05 + 0.05 * (i % 3)])
        if i % 2 == 0:
            d = torch.randn(points, 3, generator=g)
            surface = d / d.norm(dim=1, keepdim=True)
        else:
            surface = 2 * torch.rand(points, 3, generator=g) - 1
            face = torch.randint(3, (points,), generator=g)
            surface[torch.arange(points), face] = torch.sign(surface[torch.arange(points), face])
        clouds.append(size * surface + offset)
    return torch.stack(clouds)


@pytest.fixture(scope="module")
def trained():
    seen = []
    encoder, history = pretrain_pointnet(shape_clouds(), TINY, progress=lambda s, t, info: seen.append((s, t, info)))
    return encoder, history, seen


@pytest.mark.parametrize("n", [1, 7, 128, 600])
def test_encoder_shape_any_n(n):
    encoder = PointNetEncoder(PointNetConfig()).eval()
    assert encoder(torch.randn(3, n, 3) * 0.1).shape == (3, 256)


def test_encoder_permutation_invariant():
    torch.manual_seed(0)
    encoder = PointNetEncoder(TINY).eval()
    points = torch.randn(4, 50, 3) * 0.1
    shuffled = points[:, torch.randperm(50)]
    torch.testing.assert_close(encoder(points), encoder(shuffled))


def test_encoder_keeps_position():
    """No centring: a translated cloud gives a different feature."""
    encoder = PointNetEncoder(TINY).eval()
    points = torch.randn(1, 50, 3) * 0.02
    assert not torch.allclose(encoder(points), encoder(points + torch.tensor([0.0, 0.0, 0.1])))


def test_fused_encoder_matches_the_frozen_encoder():
    """BatchNorm folded into the 1x1 convolutions (the lift env's inference copy) gives the same features."""
    torch.manual_seed(0)
    encoder = PointNetEncoder(PointNetConfig(feature_dim=64, encoder_widths=(16, 32)))
    for module in encoder.modules():  # non-trivial running statistics and affine parameters
        if isinstance(module, torch.nn.BatchNorm1d):
            module.running_mean.uniform_(-1.0, 1.0)
            module.running_var.uniform_(0.5, 2.0)
            module.weight.data.uniform_(0.5, 1.5)
            module.bias.data.uniform_(-0.5, 0.5)
    with pytest.raises(RuntimeError, match="frozen"):
        encoder.fused()
    encoder.freeze()
    clouds = shape_clouds(count=5, points=96)
    fused = encoder.fused()
    with torch.no_grad():
        expected = encoder(clouds)
    assert torch.allclose(fused(clouds), expected, atol=1e-5, rtol=1e-5)
    assert fused(clouds).shape == (5, 64)
    with pytest.raises(ValueError, match="expects points"):
        fused(clouds[0])
    # the numpy path the lift env uses: same numbers from float64 or float32 arrays
    assert np.array_equal(fused.encode_numpy(clouds.numpy()), fused(clouds).numpy())
    assert np.allclose(fused.encode_numpy(clouds.numpy().astype(np.float64)), expected.numpy(), atol=1e-5, rtol=1e-5)
    with pytest.raises(ValueError, match="expects points"):
        fused.encode_numpy(clouds[0].numpy())


def test_chamfer_analytic():
    cloud = torch.randn(2, 40, 3)
    torch.testing.assert_close(chamfer_distance(cloud, cloud), torch.zeros(2), atol=1e-5, rtol=0)
    t = torch.tensor([0.3, -0.2, 0.5])
    point = torch.randn(1, 1, 3)
    torch.testing.assert_close(chamfer_distance(point, point + t), 2 * t.square().sum()[None])
    # unit grid shifted by less than half its spacing: every nearest neighbour is the point's own translate
    grid = torch.stack(torch.meshgrid(*[torch.arange(3.0)] * 3, indexing="ij"), -1).reshape(1, -1, 3)
    small = torch.tensor([0.1, 0.2, -0.1])
    torch.testing.assert_close(chamfer_distance(grid, grid + small), 2 * small.square().sum()[None])


def test_pretraining_lowers_loss_and_freezes(trained):
    encoder, history, seen = trained
    losses = [h["loss"] for h in history]
    assert [h["step"] for h in history] == [1, *range(10, 101, 10)]
    assert sum(losses[-3:]) / 3 < 0.5 * losses[0], losses  # minibatch losses are noisy: mean of the last three
    assert not encoder.training and not any(p.requires_grad for p in encoder.parameters())
    encoder.train()  # a policy's .train() must not unfreeze BatchNorm statistics
    assert not encoder.training
    assert [s for s, _, _ in seen] == [1, *range(10, 101, 10)] and seen[-1][1] == 100 and "loss" in seen[-1][2]


def test_pretraining_accepts_sampler():
    data = shape_clouds(4, 32)
    cfg = TINY.model_copy(update={"steps": 3})
    encoder, history = pretrain_pointnet(lambda b, g: data[torch.randint(4, (b,), generator=g)], cfg)
    assert encoder(data).shape == (4, 32) and history[-1]["step"] == 3


def test_save_load_round_trip(trained, tmp_path):
    encoder, _, _ = trained
    path = save_encoder(tmp_path / "pointnet.pt", encoder, TINY)
    loaded, cfg = load_encoder(path)
    assert cfg == TINY and not loaded.training
    clouds = shape_clouds(5, 90, seed=1)
    torch.testing.assert_close(loaded(clouds), encoder(clouds), rtol=0, atol=0)


def test_load_errors(tmp_path):
    with pytest.raises(MultigraspError, match="not found.*pretraining"):
        load_encoder(tmp_path / "missing.pt")
    corrupt = tmp_path / "corrupt.pt"
    corrupt.write_bytes(b"not a torch file")
    with pytest.raises(MultigraspError, match="corrupt.*delete it and re-run"):
        load_encoder(corrupt)
    other = tmp_path / "other.pt"
    torch.save({"weights": torch.zeros(2)}, other)
    with pytest.raises(MultigraspError, match="not a PointNet encoder file"):
        load_encoder(other)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_pretraining_and_load(tmp_path):
    cfg = TINY.model_copy(update={"steps": 3})
    encoder, _ = pretrain_pointnet(shape_clouds().cuda(), cfg)
    loaded, _ = load_encoder(save_encoder(tmp_path / "pointnet.pt", encoder, cfg), device="cuda")
    clouds = shape_clouds(5, 90, seed=1).cuda()
    torch.testing.assert_close(loaded(clouds), encoder(clouds))

"""Generator networks: PointNet++ sampling / grouping on analytic clouds, shapes, invariances; the denoiser."""

import pytest
import torch

from components.generation import (
    GeneratorConfig,
    GraspDenoiser,
    GraspGenerator,
    ObjectInputs,
    PointNet2Encoder,
    ball_query,
    farthest_point_sampling,
    timestep_embedding,
)

torch.set_num_threads(1)

SMALL = dict(points_per_object=64, sa1_points=16, sa1_neighbours=8, sa1_widths=(16, 16), sa2_points=4,
             sa2_neighbours=8, sa2_widths=(16, 32), global_widths=(32,), model_dim=32, heads=2, blocks=2,
             time_embedding_dim=16)


def test_farthest_point_sampling_on_a_line_picks_the_extremes_then_the_middle():
    x = torch.linspace(0.0, 1.0, 11)
    points = torch.stack([x, torch.zeros_like(x), torch.zeros_like(x)], -1)[torch.randperm(11)].unsqueeze(0)
    picked = points[0, farthest_point_sampling(points, 3)[0], 0]
    # the first pick is farthest from the centroid 0.5 (an end), then the other end, then the middle
    assert sorted(picked[:2].tolist()) == [0.0, 1.0]
    assert float(picked[2]) == pytest.approx(0.5)


def test_ball_query_returns_only_points_within_the_radius_padded_with_the_nearest():
    torch.manual_seed(0)
    points = torch.rand(2, 50, 3)
    centres = points[:, :5]
    radius, k = 0.2, 12
    index = ball_query(points, centres, radius, k)  # (2, 5, k)
    assert index.shape == (2, 5, k)
    gathered = torch.gather(points.unsqueeze(1).expand(-1, 5, -1, -1), 2, index.unsqueeze(-1).expand(-1, -1, -1, 3))
    dist = (gathered - centres.unsqueeze(2)).norm(dim=-1)
    assert bool((dist <= radius + 1e-6).all())
    assert bool((index[..., 0] == torch.arange(5)).all())  # a centre's nearest point is itself
    for b in range(2):  # the number of distinct neighbours is min(k, points in the ball)
        inside = ((points[b].unsqueeze(0) - centres[b].unsqueeze(1)).norm(dim=-1) <= radius).sum(-1)
        distinct = torch.tensor([len(set(row.tolist())) for row in index[b]])
        assert bool((distinct == inside.clamp(max=k)).all())
        padded = [row[n:] for row, n in zip(index[b], distinct.tolist())]
        assert all(bool((pad == row0).all()) for pad, row0 in zip(padded, index[b, :, 0]))


def test_pointnet2_shapes_and_the_global_feature_is_invariant_to_point_order():
    cfg = GeneratorConfig(**SMALL)
    torch.manual_seed(0)
    encoder = PointNet2Encoder(cfg).eval()
    clouds = 0.03 * torch.randn(2, 3, 64, 3)
    tokens, global_feature = encoder(clouds)
    assert tokens.shape == (2, 3, cfg.sa2_points, encoder.token_dim)
    assert global_feature.shape == (2, 3, encoder.global_dim)
    shuffled = clouds[:, :, torch.randperm(64)]
    _, again = encoder(shuffled)
    assert torch.allclose(global_feature, again, atol=1e-5)


def test_timestep_embedding_is_sin_cos_of_scaled_timesteps():
    emb = timestep_embedding(torch.tensor([0, 7]), 8)
    assert emb.shape == (2, 8)
    assert torch.allclose(emb[0], torch.tensor([0.0] * 4 + [1.0] * 4))
    assert float(emb[1, 0]) == pytest.approx(float(torch.sin(torch.tensor(7.0))))


@pytest.mark.parametrize("representation,dim", [("keypoints", 93), ("joints", 31)])
def test_denoiser_output_matches_the_representation_and_masked_objects_do_not_matter(representation, dim):
    cfg = GeneratorConfig(representation=representation, max_objects=3, **SMALL)
    torch.manual_seed(0)
    model = GraspDenoiser.for_representation(cfg).eval()
    assert model.dim == dim
    clouds = 0.03 * torch.randn(2, 3, 64, 3)
    mask = torch.tensor([[True, True, False], [True, False, False]])
    x, t = torch.randn(2, dim), torch.tensor([3, 90])
    eps = model(x, t, ObjectInputs(clouds, mask))
    assert eps.shape == (2, dim) and bool(torch.isfinite(eps).all())
    clouds2 = clouds.clone()
    clouds2[0, 2] += 0.05  # change only a masked-out object
    assert torch.allclose(eps, model(x, t, ObjectInputs(clouds2, mask)), atol=1e-5)
    clouds2[0, 1] += 0.05  # change a present object
    assert not torch.allclose(eps[0], model(x, t, ObjectInputs(clouds2, mask))[0], atol=1e-5)


def test_cached_cross_attention_keys_values_give_the_same_noise_prediction():
    """The sampler's cache of the object tokens' keys / values (computed once, repeated per grasp) changes
    nothing: same eps as nn.MultiheadAttention on the tokens, with a masked-out object slot too."""
    cfg = GeneratorConfig(max_objects=3, **SMALL)
    torch.manual_seed(0)
    model = GraspDenoiser.for_representation(cfg).eval()
    objects = ObjectInputs(0.03 * torch.randn(2, 3, 64, 3), torch.tensor([[True, True, False], [True, False, True]]))
    context = model.encode(objects)
    cached = model.cache_keys_values(context)
    assert cached.keys_values is not None and len(cached.keys_values) == cfg.blocks
    x, t = torch.randn(6, 93), torch.tensor([0, 5, 50, 99, 3, 7])
    with torch.no_grad():
        plain = model(x, t, context.repeat_interleave(3))
        fast = model(x, t, cached.repeat_interleave(3))
    assert torch.allclose(plain, fast, atol=1e-5)


def test_object_slot_embedding_distinguishes_swapped_objects_only_when_enabled():
    torch.manual_seed(0)
    clouds = 0.03 * torch.randn(1, 2, 64, 3)
    swapped = clouds.flip(1)
    x, t = torch.randn(1, 93), torch.tensor([10])
    for use, differs in ((True, True), (False, False)):
        model = GraspDenoiser.for_representation(GeneratorConfig(use_object_embedding=use, **SMALL)).eval()
        a, b = model(x, t, ObjectInputs(clouds)), model(x, t, ObjectInputs(swapped))
        assert (not torch.allclose(a, b, atol=1e-5)) == differs


def test_generator_loss_backpropagates_and_sampling_returns_raw_representations():
    cfg = GeneratorConfig(diffusion_steps=5, **SMALL)
    torch.manual_seed(0)
    model = GraspGenerator(cfg)
    model.standardizer.fit(0.05 * torch.randn(64, 93) + 0.1)
    clouds = ObjectInputs(0.03 * torch.randn(4, 2, 64, 3))
    loss = model.loss(0.05 * torch.randn(4, 93) + 0.1, clouds, torch.Generator().manual_seed(0))
    loss.backward()
    assert torch.isfinite(loss) and model.denoiser.token_out.weight.grad is not None
    out = model.sample(clouds, per_scene=3, generator=torch.Generator().manual_seed(1))
    assert out.shape == (12, 93) and bool(torch.isfinite(out).all())


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_generator_trains_and_samples_on_cuda():
    cfg = GeneratorConfig(diffusion_steps=5, **SMALL)
    model = GraspGenerator(cfg).cuda()
    clouds = ObjectInputs(0.03 * torch.randn(4, 2, 64, 3, device="cuda"))
    loss = model.loss(0.05 * torch.randn(4, 93, device="cuda"), clouds, torch.Generator(device="cuda").manual_seed(0))
    loss.backward()
    out = model.sample(clouds, per_scene=2, generator=torch.Generator(device="cuda").manual_seed(1))
    assert out.is_cuda and out.shape == (8, 93) and bool(torch.isfinite(out).all())

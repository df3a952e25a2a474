"""DDPM: closed-form schedule, forward process, and a tiny model learning a 2-D two-cluster distribution (with
the paper's schedule and epsilon, and with the zero-terminal-SNR schedule and v); palm alignment about z."""

import math

import pytest
import torch
from torch import nn

from components.generation import (
    AlignedFrame,
    GeneratorConfig,
    NoiseSchedule,
    ddim_sample,
    palm_direction,
    q_sample,
    sample,
    train_diffusion,
    yaw_of,
)
from components.synthesis.pose import rot6d_to_matrix

torch.set_num_threads(1)
CENTRES = torch.tensor([[-2.0, 0.0], [2.0, 1.0]])
CLUSTER_STD = 0.15


def test_linear_schedule_alphas_cumprod_matches_the_closed_form():
    schedule = NoiseSchedule(100, 1e-4, 0.01)
    t = torch.arange(100, dtype=torch.float64)
    betas = 1e-4 + (0.01 - 1e-4) * t / 99
    assert torch.allclose(schedule.betas, betas)
    expected = torch.tensor([math.prod(1.0 - float(b) for b in betas[: k + 1]) for k in range(100)], dtype=torch.float64)
    assert torch.allclose(schedule.alphas_cumprod, expected, rtol=1e-12)
    assert float(schedule.alphas_cumprod[-1]) == pytest.approx(0.6025, abs=1e-3)  # T = 100 leaves signal
    tilde = betas[1:] * (1 - expected[:-1]) / (1 - expected[1:])
    assert torch.allclose(schedule.posterior_variance[1:], tilde)


def test_q_sample_at_t0_is_nearly_x0_and_has_the_closed_form_moments():
    schedule = NoiseSchedule(100, 1e-4, 0.01)
    x0 = torch.randn(4096, 2)
    noise = torch.randn(4096, 2)
    x_first = q_sample(schedule, x0, torch.zeros(4096, dtype=torch.long), noise)
    assert float((x_first - x0).abs().max()) < 0.06  # sqrt(1 - abar_0) = 0.01 times the noise
    ones = torch.ones(4096, 2)
    last = q_sample(schedule, ones, torch.full((4096,), 99, dtype=torch.long), noise)
    abar = float(schedule.alphas_cumprod[99])
    assert float(last.mean()) == pytest.approx(math.sqrt(abar), abs=0.03)
    assert float(last.std()) == pytest.approx(math.sqrt(1 - abar), abs=0.03)


class ToyEps(nn.Module):
    """eps(x_t, t) for 2-D data: an MLP on [x_t, sin/cos(t)]."""

    def __init__(self):
        super().__init__()
        self.net = nn.Sequential(nn.Linear(4, 128), nn.SiLU(), nn.Linear(128, 128), nn.SiLU(), nn.Linear(128, 2))

    def forward(self, x, t, cond):
        phase = t.float().unsqueeze(-1) / 100.0 * math.pi
        return self.net(torch.cat([x, phase.sin(), phase.cos()], dim=-1))


@pytest.mark.parametrize("options", [{}, {"zero_terminal_snr": True, "prediction": "v"}],
                         ids=["paper-epsilon", "zero-snr-v"])
def test_tiny_ddpm_trained_on_two_clusters_samples_both_clusters(options):
    torch.manual_seed(0)
    cfg = GeneratorConfig(lr=3e-3, batch_size=256, seed=0, log_every=100, **options)
    schedule = NoiseSchedule.from_config(cfg)
    model = ToyEps()  # with prediction 'v' the same network learns v

    def batch(step, generator):
        which = torch.randint(2, (cfg.batch_size,), generator=generator)
        return CENTRES[which] + CLUSTER_STD * torch.randn(cfg.batch_size, 2, generator=generator), None

    history = train_diffusion(model, schedule, batch, cfg, steps=400)
    assert history[-1]["loss"] < history[0]["loss"]
    samples = [sample(model, schedule, (1000, 2), None, torch.Generator().manual_seed(1))]
    if options:
        samples.append(ddim_sample(model, schedule, (1000, 2), None, 25, generator=torch.Generator().manual_seed(1),
                                   spacing="trailing"))
    for x in samples:
        nearest = torch.cdist(x, CENTRES).min(-1)
        share = (nearest.indices == 0).float().mean()
        assert 0.3 < float(share) < 0.7  # both modes, roughly balanced
        assert float((nearest.values < 0.6).float().mean()) > 0.8  # most samples land on a cluster
        assert torch.allclose(x.mean(0), CENTRES.mean(0), atol=0.4)


def test_palm_alignment_round_trip_and_the_aligned_palm_points_along_plus_x():
    g = torch.Generator().manual_seed(0)
    R = rot6d_to_matrix(torch.randn(8, 6, generator=g, dtype=torch.float64))
    p = torch.randn(8, 3, generator=g, dtype=torch.float64)
    pivot = torch.randn(8, 3, generator=g, dtype=torch.float64)
    points = torch.randn(8, 2, 5, 3, generator=g, dtype=torch.float64)
    frame = AlignedFrame.from_palm(R, pivot)
    p_a, R_a = frame.pose_to_aligned(p, R)
    n_a = palm_direction(R_a)
    assert torch.allclose(n_a[:, 1], torch.zeros(8, dtype=torch.float64), atol=1e-12)
    assert bool((n_a[:, 0] > 0).all())
    assert torch.allclose(n_a[:, 2], palm_direction(R)[:, 2])  # rotation about z keeps heights
    p_b, R_b = frame.pose_from_aligned(p_a, R_a)
    assert torch.allclose(p_b, p) and torch.allclose(R_b, R)
    assert torch.allclose(frame.points_from_aligned(frame.points_to_aligned(points)), points)
    # the hand's points move rigidly with the objects: relative positions in the palm frame are unchanged
    rel = (points[:, 0] - p.unsqueeze(1)) @ R
    rel_a = (frame.points_to_aligned(points)[:, 0] - p_a.unsqueeze(1)) @ R_a
    assert torch.allclose(rel, rel_a)


def test_a_desired_palm_direction_is_aligned_with_plus_x():
    direction = torch.tensor([[0.0, 1.0, 0.0], [-1.0, -1.0, 0.3]])
    frame = AlignedFrame.from_direction(direction)
    aligned = frame.points_to_aligned(direction.unsqueeze(1))[:, 0]
    assert torch.allclose(yaw_of(aligned), torch.zeros(2), atol=1e-6)

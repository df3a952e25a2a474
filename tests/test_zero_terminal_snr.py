"""Zero-terminal-SNR schedule and v-prediction (components.generation.diffusion) against analytic answers:
the rescaled schedule's ends, the exact v-model of a one-point distribution lands on it with every sampler,
the trailing DDIM spacing, the config rule (the two-cluster toy training with v is in
test_generation_diffusion.py)."""

import pytest
import torch
from pydantic import ValidationError

from components.generation import (
    GeneratorConfig,
    GraspGenerator,
    NoiseSchedule,
    ObjectInputs,
    SamplerConfig,
    ddim_sample,
    ddim_timesteps,
    diffusion_loss,
    q_sample,
    sample,
)
from components.generation.diffusion import model_estimates, velocity

torch.set_num_threads(1)
TARGET = torch.tensor([[0.3, -1.2, 2.0]], dtype=torch.float64)


def _exact_v(schedule):
    """v of the one-point distribution at TARGET: eps = (x_t - sqrt(abar) x*) / sqrt(1 - abar)."""

    def model(x, t, cond):
        abar = schedule.alphas_cumprod[t].unsqueeze(-1)
        eps = (x - abar.sqrt() * TARGET) / (1.0 - abar).sqrt()
        return abar.sqrt() * eps - (1.0 - abar).sqrt() * TARGET

    return model


def test_rescaled_schedule_ends_at_zero_snr_and_keeps_the_first_step():
    plain = NoiseSchedule(100, 1e-4, 0.01)
    zero = NoiseSchedule(100, 1e-4, 0.01, zero_terminal_snr=True, prediction="v")
    assert float(zero.alphas_cumprod[-1]) == pytest.approx(0.0, abs=1e-20)
    assert float(zero.betas[-1]) == pytest.approx(1.0)
    torch.testing.assert_close(zero.alphas_cumprod[0], plain.alphas_cumprod[0])
    # sqrt(abar) is an affine map of the linear schedule's: s' = (s - s_T) s_0 / (s_0 - s_T)
    s = plain.alphas_cumprod.sqrt()
    s0, sT = float(s[0]), float(s[-1])
    torch.testing.assert_close(zero.alphas_cumprod.sqrt(), (s - sT) * s0 / (s0 - sT))
    assert bool((zero.betas > 0).all()) and bool((zero.betas <= 1).all())
    assert bool((zero.alphas_cumprod[1:] < zero.alphas_cumprod[:-1]).all())  # strictly less signal at every step


def test_v_targets_and_estimates_invert_each_other():
    schedule = NoiseSchedule(100, 1e-4, 0.01, zero_terminal_snr=True, prediction="v")
    gen = torch.Generator().manual_seed(0)
    x0 = torch.randn(8, 5, generator=gen, dtype=torch.float64)
    noise = torch.randn(8, 5, generator=gen, dtype=torch.float64)
    t = torch.tensor([0, 1, 10, 50, 90, 98, 99, 99])
    x_t = q_sample(schedule, x0, t, noise)
    x0_hat, eps_hat = model_estimates(schedule, x_t, t, velocity(schedule, x0, t, noise))
    torch.testing.assert_close(x0_hat, x0)
    torch.testing.assert_close(eps_hat, noise)
    # at abar = 0 (t = T-1), v = -x_0 whatever the noise
    torch.testing.assert_close(velocity(schedule, x0, t, noise)[-1], -x0[-1])


def test_exact_v_model_of_one_point_lands_on_it_with_every_sampler():
    schedule = NoiseSchedule(100, 1e-4, 0.01, zero_terminal_snr=True, prediction="v")
    model = _exact_v(schedule)
    out = sample(model, schedule, (4, 3), None, torch.Generator().manual_seed(1), dtype=torch.float64)
    torch.testing.assert_close(out, TARGET.expand(4, 3), rtol=0, atol=1e-9)
    for spacing in ("leading", "trailing"):
        for steps in (1, 5, 25, 100):
            out = ddim_sample(model, schedule, (4, 3), None, steps, generator=torch.Generator().manual_seed(2),
                              dtype=torch.float64, spacing=spacing)
            torch.testing.assert_close(out, TARGET.expand(4, 3), rtol=0, atol=1e-9)


def test_trailing_spacing_starts_at_the_last_training_step():
    assert ddim_timesteps(100, 25, "trailing") == list(range(3, 100, 4))
    assert ddim_timesteps(100, 100, "trailing") == list(range(100))
    assert ddim_timesteps(100, 1, "trailing") == [99]
    steps = ddim_timesteps(100, 30, "trailing")
    assert len(steps) == 30 and steps[-1] == 99 and steps == sorted(set(steps))


def test_zero_terminal_snr_needs_v_prediction():
    with pytest.raises(ValidationError, match="prediction='v'"):
        GeneratorConfig(zero_terminal_snr=True)
    with pytest.raises(ValueError, match="prediction='v'"):
        NoiseSchedule(100, 1e-4, 0.01, zero_terminal_snr=True)
    with pytest.raises(ValidationError, match="diffusion_steps >= 2"):
        GeneratorConfig(zero_terminal_snr=True, prediction="v", diffusion_steps=1)
    schedule = NoiseSchedule.from_config(GeneratorConfig(zero_terminal_snr=True, prediction="v"))
    assert schedule.prediction == "v" and float(schedule.alphas_cumprod[-1]) < 1e-20


def test_v_loss_is_zero_for_the_exact_model_and_positive_for_the_noise_model():
    schedule = NoiseSchedule(100, 1e-4, 0.01, zero_terminal_snr=True, prediction="v")
    x0 = TARGET.expand(64, 3)
    assert float(diffusion_loss(_exact_v(schedule), schedule, x0, None, torch.Generator().manual_seed(0))) < 1e-20
    noise_model = NoiseSchedule(100, 1e-4, 0.01)

    def exact_eps(x, t, cond):
        abar = noise_model.alphas_cumprod[t].unsqueeze(-1)
        return (x - abar.sqrt() * TARGET) / (1.0 - abar).sqrt()

    assert float(diffusion_loss(exact_eps, noise_model, x0, None, torch.Generator().manual_seed(0))) < 1e-20


def test_generator_with_v_prediction_trains_a_step_and_samples_finite():
    small = dict(points_per_object=64, sa1_points=16, sa1_widths=(16,), sa2_points=4, sa2_widths=(32,),
                 global_widths=(32,), model_dim=32, heads=2, blocks=1, time_embedding_dim=16)
    torch.manual_seed(0)
    model = GraspGenerator(GeneratorConfig(diffusion_steps=20, zero_terminal_snr=True, prediction="v", **small))
    objects = ObjectInputs(0.03 * torch.randn(2, 2, 64, 3))
    sampler = SamplerConfig(method="ddim", steps=5, spacing="trailing")
    out = model.sample(objects, per_scene=3, generator=torch.Generator().manual_seed(5), sampler=sampler)
    assert out.shape == (6, model.denoiser.dim) and torch.isfinite(out).all()
    out = model.sample(objects, per_scene=3, generator=torch.Generator().manual_seed(5))
    assert torch.isfinite(out).all()

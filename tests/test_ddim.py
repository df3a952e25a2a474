"""The strided DDIM sampler (components.generation.diffusion.ddim_*) against analytic answers:
eta = 1 on every timestep is the ancestral DDPM step; with the exact noise model of a one-point data
distribution every step count lands on that point; the generator's ``sampler`` switch uses it."""

import torch

from components.generation import (
    GeneratorConfig,
    GraspGenerator,
    NoiseSchedule,
    ObjectInputs,
    SamplerConfig,
    ddim_sample,
    ddim_step,
    ddim_timesteps,
    p_sample,
    sample,
)


SMALL = dict(points_per_object=64, sa1_points=16, sa1_widths=(16,), sa2_points=4, sa2_widths=(32,),
             global_widths=(32,), model_dim=32, heads=2, blocks=1, time_embedding_dim=16)


def _toy_model(x, t, cond):
    return torch.sin(x + 0.01 * t[:, None].to(x.dtype))


def test_timesteps_use_leading_spacing():
    assert ddim_timesteps(100, 25) == list(range(0, 100, 4))
    assert ddim_timesteps(100, 100) == list(range(100))
    assert ddim_timesteps(100, 30)[-1] == 87  # stride floor(100 / 30) = 3


def test_eta_one_on_every_step_is_the_ancestral_ddpm_step():
    schedule = NoiseSchedule(100, 1e-4, 0.01)
    x = torch.randn(16, 7, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    for t in (99, 60, 20, 10):  # at t < 10 the DDPM form loses digits to 1 - abar in float32 buffers' cast
        a = p_sample(_toy_model, schedule, x, t, None, torch.Generator().manual_seed(1))
        b = ddim_step(_toy_model, schedule, x, t, t - 1, None, 1.0, torch.Generator().manual_seed(1))
        torch.testing.assert_close(a, b, rtol=1e-6, atol=1e-6)


def test_exact_noise_model_of_one_point_lands_on_it_for_any_step_count():
    schedule = NoiseSchedule(100, 1e-4, 0.01)
    target = torch.tensor([[0.3, -1.2, 2.0]], dtype=torch.float64)

    def exact(x, t, cond):  # eps = (x_t - sqrt(abar_t) x*) / sqrt(1 - abar_t)
        abar = schedule.alphas_cumprod[t].unsqueeze(-1)
        return (x - abar.sqrt() * target) / (1.0 - abar).sqrt()

    for steps in (1, 5, 25, 100):
        out = ddim_sample(exact, schedule, (4, 3), None, steps, generator=torch.Generator().manual_seed(2),
                          dtype=torch.float64)
        torch.testing.assert_close(out, target.expand(4, 3), rtol=0, atol=1e-9)


def test_generator_sampler_switch_is_deterministic_with_eta_zero():
    torch.manual_seed(0)
    model = GraspGenerator(GeneratorConfig(diffusion_steps=20, **SMALL))
    objects = ObjectInputs(0.03 * torch.randn(2, 2, 64, 3))
    ddim = SamplerConfig(method="ddim", steps=5)
    a = model.sample(objects, per_scene=3, generator=torch.Generator().manual_seed(5), sampler=ddim)
    b = model.sample(objects, per_scene=3, generator=torch.Generator().manual_seed(5), sampler=ddim)
    assert a.shape == (6, model.denoiser.dim) and torch.isfinite(a).all()
    torch.testing.assert_close(a, b)
    ddpm = model.sample(objects, per_scene=3, generator=torch.Generator().manual_seed(5))
    assert not torch.allclose(a, ddpm)


def test_denoise_from_any_timestep_with_the_exact_noise_model_lands_on_the_point():
    from components.generation import denoise_from, q_sample

    schedule = NoiseSchedule(100, 1e-4, 0.01)
    target = torch.tensor([[0.3, -1.2, 2.0]], dtype=torch.float64)

    def exact(x, t, cond):
        abar = schedule.alphas_cumprod[t].unsqueeze(-1)
        return (x - abar.sqrt() * target) / (1.0 - abar).sqrt()

    gen = torch.Generator().manual_seed(3)
    for t in (0, 10, 50, 99):
        x_t = q_sample(schedule, target.expand(4, 3), torch.full((4,), t), torch.randn(4, 3, generator=gen,
                                                                                         dtype=torch.float64))
        out = denoise_from(exact, schedule, x_t, t, None, generator=gen)
        torch.testing.assert_close(out, target.expand(4, 3), rtol=0, atol=1e-9)
    # sample() is denoise_from(T - 1) of N(0, I) draws: the same generator state gives the same result
    a = sample(_toy_model, schedule, (3, 2), None, torch.Generator().manual_seed(5), dtype=torch.float64)
    start = torch.randn(3, 2, generator=torch.Generator().manual_seed(5), dtype=torch.float64)
    gen = torch.Generator().manual_seed(5)
    torch.randn(3, 2, generator=gen, dtype=torch.float64)
    b = denoise_from(_toy_model, schedule, start, 99, None, gen)
    torch.testing.assert_close(a, b, rtol=0, atol=0)

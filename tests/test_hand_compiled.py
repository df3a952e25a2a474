"""Shadow Hand distances with compile_distance_kernels=True (torch.compile; ~15-30 s to compile: slow)."""

import pytest
import torch

from components.hand import HandConfig, HandModel


@pytest.mark.slow
def test_compiled_distance_kernels_match_eager():
    """compile_distance_kernels=True (torch.compile, ~15-30 s to compile) gives the eager distances."""
    eager = HandModel(HandConfig(), dtype=torch.float32)
    compiled = HandModel(HandConfig(compile_distance_kernels=True), dtype=torch.float32)
    generator = torch.Generator().manual_seed(11)
    q = eager.sample_joint_angles(4, generator).requires_grad_()
    p = torch.zeros(4, 3, requires_grad=True)
    R = torch.eye(3).expand(4, 3, 3).clone().requires_grad_()
    points = torch.randn(4, 300, 3, generator=generator) * 0.06 + torch.tensor([0.0, 0.0, 0.08])
    d_eager = eager.signed_distance(points, p, R, q)
    d_compiled = compiled.signed_distance(points, p, R, q)
    assert torch.allclose(d_eager, d_compiled, atol=2e-6)
    grads = [torch.autograd.grad(d.sum(), (p, R, q)) for d in (d_eager, d_compiled)]
    for g_eager, g_compiled in zip(*grads):
        assert torch.allclose(g_eager, g_compiled, atol=1e-4)

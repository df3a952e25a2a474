"""Pre-trained PointNet encoder of hand and object point clouds (Qi et al. 2017), frozen for the RL policy.

MultiGrasp's execution policy observes the hand and each object through a pre-trained PointNet feature.
This module trains that feature without labels, as the encoder of a point-cloud autoencoder
(Achlioptas et al. 2018), then freezes it.

Encoder  f(P) = max_{i=1..N} h(p_i / s),   P = {p_i} in R^{N x 3},  f(P) in R^{feature_dim}
    h is a shared per-point MLP (1x1 convolutions, each followed by BatchNorm (``norm``) and ReLU, widths
    ``encoder_widths`` then ``feature_dim``); the max over points makes f invariant to the order of the
    points and lets it take any N.  s = ``input_scale_m`` brings coordinates in metres to order 1.

Decoder  g(f) in R^{M x 3}: an MLP (``decoder_widths``, ReLU) whose last layer outputs M * 3 numbers,
    M = ``points_per_cloud``; it reconstructs the *scaled* cloud P / s.

Loss     symmetric Chamfer distance between g(f(P~)) and P / s (:func:`chamfer_distance`), where P~ is
    the augmented input: the training cloud rotated about the palm's z axis by an angle drawn uniformly
    in [-``augment_rotation_rad``, ``augment_rotation_rad``] (the target is rotated too) and jittered by
    N(0, ``jitter_std_m``^2) per coordinate (the target is not: a denoising autoencoder).

Clouds are *not* centred or rescaled per cloud: they are given in the palm frame and the policy needs
to know where each object is relative to the palm, which centring would erase.  The only normalisation
is the fixed global scale s, which keeps that information.

After :func:`pretrain_pointnet` the encoder is frozen (:meth:`PointNetEncoder.freeze`): eval mode, no
parameter requires grad, and a later ``.train()`` of a policy that holds it leaves it in eval mode, so
its BatchNorm statistics never move.
"""

from __future__ import annotations

import io
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Literal, Optional, Union

import numpy as np
import torch
from pydantic import Field, PositiveInt, ValidationError
from torch import Tensor, nn
from torch.nn.utils.fusion import fuse_conv_bn_weights

from components.config_base import Section
from components.errors import MultigraspError
from components.fileio import atomic_write_bytes

#: progress(step, total, info): called at step 1, every ``log_every`` steps and at the last step
ProgressFn = Callable[[int, int, dict], None]
#: sampler(batch_size, generator) -> (batch_size, N, 3) fresh training clouds in the palm frame (m);
#: the generator lives on the training device
CloudSampler = Callable[[int, torch.Generator], Tensor]

_FILE_FORMAT = "multigrasp.pointnet_encoder"
_FILE_VERSION = 1


class PointNetConfig(Section):
    """PointNet encoder / decoder widths and its autoencoder pretraining."""

    # ------------------------------------------------------------------ architecture
    feature_dim: int = Field(256, ge=1, description="Width of the max-pooled feature of one cloud (MultiGrasp: 256).")
    encoder_widths: tuple[PositiveInt, ...] = Field(
        (32, 64),
        description="Hidden widths of the shared per-point MLP before its last layer (width feature_dim).  (32, 64): "
        "the lift env encodes 3 clouds of 128 points every few steps on one CPU thread, and (64, 128, 256) cost "
        "1.5 ms per call there, half the physics of a step (benchmarks/sim.py).")
    decoder_widths: tuple[PositiveInt, ...] = Field(
        (256, 256), description="Hidden widths of the MLP decoder from the feature to points_per_cloud * 3 coordinates.")
    norm: Literal["batch", "none"] = Field(
        "batch", description="Normalisation after each per-point layer: BatchNorm (as in PointNet) or none.")
    input_scale_m: float = Field(
        0.1, gt=0.0, description="Coordinates (m) are divided by this fixed scale before the MLP; no per-cloud centring.")

    # ------------------------------------------------------------------ pretraining
    points_per_cloud: int = Field(
        128, ge=1, description="Points drawn from each training cloud per step, and points the decoder outputs "
        "(the lift env's clouds have lift.hand_cloud_points = lift.object_cloud_points = 128).")
    steps: int = Field(2000, ge=0, description="Adam steps of autoencoder pretraining.")
    batch_size: int = Field(32, ge=1, description="Clouds per pretraining minibatch.")
    lr: float = Field(1e-3, gt=0.0, description="Adam learning rate.")
    augment_rotation_rad: float = Field(
        math.pi, ge=0.0, le=math.pi,
        description="Training clouds are rotated about the palm z axis by an angle uniform in [-a, a]; 0 disables.")
    jitter_std_m: float = Field(
        0.002, ge=0.0, description="Std (m) of Gaussian noise added to each input coordinate; the target stays clean.")
    seed: int = Field(0, description="Seed of the weight initialisation and of minibatch / augmentation sampling.")
    log_every: int = Field(100, ge=1, description="Steps between history entries and progress calls.")


# ---------------------------------------------------------------------------------------------- modules


def _check_points(points: Tensor) -> None:
    if points.dim() != 3 or points.shape[-1] != 3 or points.shape[1] == 0:
        raise ValueError(f"PointNetEncoder expects points of shape (B, N >= 1, 3), got {tuple(points.shape)}")


class PointNetEncoder(nn.Module):
    """Shared per-point MLP then max-pool over points:  (B, N, 3) -> (B, feature_dim), any N >= 1."""

    def __init__(self, cfg: PointNetConfig):
        super().__init__()
        widths = (3, *cfg.encoder_widths, cfg.feature_dim)
        layers: list[nn.Module] = []
        for c_in, c_out in zip(widths[:-1], widths[1:]):
            layers.append(nn.Conv1d(c_in, c_out, kernel_size=1, bias=cfg.norm == "none"))
            if cfg.norm == "batch":
                layers.append(nn.BatchNorm1d(c_out))
            layers.append(nn.ReLU())
        self.mlp = nn.Sequential(*layers)
        self.input_scale = cfg.input_scale_m
        self.feature_dim = cfg.feature_dim
        self.frozen = False

    def forward(self, points: Tensor) -> Tensor:
        """points (B, N, 3) in the palm frame (m)  ->  features (B, feature_dim)."""
        _check_points(points)
        per_point = self.mlp((points / self.input_scale).transpose(1, 2))  # (B, feature_dim, N)
        return per_point.amax(dim=2)

    def freeze(self) -> "PointNetEncoder":
        """Eval mode and no gradients, for good: a later ``.train()`` keeps it in eval mode."""
        self.frozen = True
        self.requires_grad_(False)
        return self.eval()

    def train(self, mode: bool = True) -> "PointNetEncoder":
        return super().train(mode and not self.frozen)

    def fused(self) -> "FusedPointNetEncoder":
        """A faster inference copy with BatchNorm folded in (:class:`FusedPointNetEncoder`); frozen encoders only,
        so that the copy cannot go stale."""
        if not self.frozen:
            raise RuntimeError("PointNetEncoder.fused() needs a frozen encoder (call freeze() first)")
        return FusedPointNetEncoder(self)


class FusedPointNetEncoder:
    """Inference copy of a frozen :class:`PointNetEncoder` for the CPU lift env: each BatchNorm folded into the
    1x1 convolution before it (``torch.nn.utils.fusion.fuse_conv_bn_weights``), the layers run as ``addmm``:

        h_{k+1} = relu(h_k W_k^T + b_k),   W_k = diag(g_k / sqrt(v_k + eps)) C_k,   b_k = (c_k - m_k) g_k / sqrt(v_k + eps) + beta_k.

    Same features as the encoder (to float rounding, tested).  Why: the env encodes 3 clouds x 128 points
    every ``lift.feature_period`` steps between PyBullet steps; one call costs 0.25 ms against the module's
    0.39 ms (1 thread, warm; benchmarks/sim.py's workload).  torch rather than numpy: numpy's BLAS ignores
    ``torch.set_num_threads`` and its spinning threads halve the speed of two collector workers on two cores.
    The weights are a snapshot, hence frozen encoders only (:meth:`PointNetEncoder.fused`)."""

    def __init__(self, encoder: PointNetEncoder):
        self.layers: list[tuple[Tensor, Tensor]] = []  # [(W (c_in, c_out), b (c_out,))]
        modules = list(encoder.mlp)
        with torch.no_grad():
            for k, module in enumerate(modules):
                if not isinstance(module, nn.Conv1d):
                    continue
                w = module.weight
                b = torch.zeros(w.shape[0], dtype=w.dtype, device=w.device) if module.bias is None else module.bias
                following = modules[k + 1] if k + 1 < len(modules) else None
                if isinstance(following, nn.BatchNorm1d):
                    w, b = fuse_conv_bn_weights(w, b, following.running_mean, following.running_var, following.eps,
                                                following.weight, following.bias)
                self.layers.append((w.detach()[:, :, 0].T.contiguous(), b.detach().clone()))
            # the input scaling folded into the first layer: (x / s) W = x (W / s)
            first_w, first_b = self.layers[0]
            self.layers[0] = ((first_w / encoder.input_scale).contiguous(), first_b)
        self.input_scale = encoder.input_scale
        self.feature_dim = encoder.feature_dim

    def __call__(self, points: Tensor) -> Tensor:
        """points (B, N, 3) in the palm frame (m)  ->  features (B, feature_dim); the
        :data:`components.execution.clouds.Encoder` interface.  No grad mode needed: the weights are detached
        copies, so nothing is recorded."""
        _check_points(points)
        batch, n = points.shape[:2]
        return self._encode(points.reshape(batch * n, 3), batch, n)

    def _encode(self, h: Tensor, batch: int, n: int) -> Tensor:
        """The fused layers on the flat points h (B N, 3), then the max over each cloud's N points.  -> (B, F)."""
        for w, b in self.layers:
            h = torch.addmm(b, h, w).relu_()
        return h.view(batch, n, -1).amax(dim=1)

    def encode_numpy(self, points: np.ndarray) -> np.ndarray:
        """The same on numpy arrays (B, N, 3) -> (B, feature_dim) float32, with as few torch calls as possible: the
        lift env calls it between PyBullet steps, where the first torch calls after the physics cost 15-70 us each
        (a grad-mode switch, a reshape, a division each cost more than a small matrix product there; measured in
        the benchmark's loop).  CPU weights only."""
        points = np.asarray(points)
        if points.ndim != 3 or points.shape[-1] != 3 or points.shape[1] == 0:
            raise ValueError(f"PointNetEncoder expects points of shape (B, N >= 1, 3), got {points.shape}")
        batch, n = points.shape[:2]
        h = torch.from_numpy(np.ascontiguousarray(points.reshape(batch * n, 3), dtype=np.float32))
        return self._encode(h, batch, n).numpy()


class PointDecoder(nn.Module):
    """MLP from a feature to a point cloud:  (B, feature_dim) -> (B, points_per_cloud, 3), in scaled units."""

    def __init__(self, cfg: PointNetConfig):
        super().__init__()
        widths = (cfg.feature_dim, *cfg.decoder_widths)
        layers: list[nn.Module] = []
        for c_in, c_out in zip(widths[:-1], widths[1:]):
            layers += [nn.Linear(c_in, c_out), nn.ReLU()]
        layers.append(nn.Linear(widths[-1], cfg.points_per_cloud * 3))
        self.mlp = nn.Sequential(*layers)
        self.num_points = cfg.points_per_cloud

    def forward(self, features: Tensor) -> Tensor:
        """features (B, feature_dim) -> points (B, points_per_cloud, 3) in units of input_scale_m."""
        return self.mlp(features).view(features.shape[0], self.num_points, 3)


class PointNetAutoencoder(nn.Module):
    """Encoder + decoder, trained by the Chamfer distance between the reconstruction and the scaled cloud."""

    def __init__(self, cfg: PointNetConfig):
        super().__init__()
        self.encoder = PointNetEncoder(cfg)
        self.decoder = PointDecoder(cfg)

    def forward(self, points: Tensor) -> Tensor:
        """points (B, N, 3) (m) -> reconstruction (B, points_per_cloud, 3) in units of input_scale_m."""
        return self.decoder(self.encoder(points))

    def loss(self, inputs: Tensor, targets: Tensor) -> Tensor:
        """Mean Chamfer distance (scaled units) between the reconstruction of inputs (B, N, 3) and targets (B, K, 3) (m)."""
        return chamfer_distance(self(inputs), targets / self.encoder.input_scale).mean()


def chamfer_distance(a: Tensor, b: Tensor) -> Tensor:
    """Symmetric Chamfer distance between batched clouds a (B, N, 3) and b (B, M, 3)  ->  (B,).

    CD(A, B) = 1/|A| sum_{x in A} min_{y in B} |x - y|^2  +  1/|B| sum_{y in B} min_{x in A} |x - y|^2,
    with squared Euclidean distances (so a one-point cloud and its translate by t are 2 |t|^2 apart).
    The nearest neighbours are found with ``torch.cdist`` without gradient, then |x - y|^2 is recomputed
    for those pairs: same value and gradient as differentiating the min, without cdist's slow backward.
    """
    with torch.no_grad():
        dist = torch.cdist(a, b)  # (B, N, M)
        nearest_in_b, nearest_in_a = dist.argmin(dim=2), dist.argmin(dim=1)  # (B, N), (B, M)
    a_to_b = (a - _gather_points(b, nearest_in_b)).square().sum(-1).mean(dim=1)
    b_to_a = (b - _gather_points(a, nearest_in_a)).square().sum(-1).mean(dim=1)
    return a_to_b + b_to_a


def _gather_points(points: Tensor, idx: Tensor) -> Tensor:
    """points (B, N, 3), idx (B, K) -> points[b, idx[b, k]] (B, K, 3)."""
    return torch.gather(points, 1, idx.unsqueeze(-1).expand(-1, -1, points.shape[-1]))


# ---------------------------------------------------------------------------------------------- pretraining


def _draw_points(clouds: Tensor, num: int, generator: torch.Generator) -> Tensor:
    """``num`` points of each cloud (B, N, 3): without replacement when N >= num, else with. -> (B, num, 3)."""
    batch, n = clouds.shape[:2]
    if n >= num:
        idx = torch.rand(batch, n, generator=generator, device=clouds.device).argsort(dim=1)[:, :num]
    else:
        idx = torch.randint(n, (batch, num), generator=generator, device=clouds.device)
    return _gather_points(clouds, idx)


def _rotate_z(points: Tensor, max_angle: float, generator: torch.Generator) -> Tensor:
    """Rotate each cloud of points (B, N, 3) about z by an angle uniform in [-max_angle, max_angle]."""
    angle = (2.0 * torch.rand(points.shape[0], generator=generator, device=points.device) - 1.0) * max_angle
    cos, sin = angle.cos()[:, None], angle.sin()[:, None]
    x, y, z = points.unbind(-1)
    return torch.stack((cos * x - sin * y, sin * x + cos * y, z), dim=-1)


def _training_pair(data: Union[Tensor, CloudSampler], cfg: PointNetConfig, generator: torch.Generator,
                   device: torch.device) -> tuple[Tensor, Tensor]:
    """One augmented minibatch -> (inputs, targets), both (batch_size, points_per_cloud, 3) in metres."""
    if callable(data):
        clouds = data(cfg.batch_size, generator).to(device=device, dtype=torch.float32)
    else:
        clouds = data[torch.randint(data.shape[0], (cfg.batch_size,), generator=generator, device=device)]
    targets = _draw_points(clouds, cfg.points_per_cloud, generator)
    if cfg.augment_rotation_rad > 0.0:
        targets = _rotate_z(targets, cfg.augment_rotation_rad, generator)
    noise = torch.randn(targets.shape, generator=generator, device=device) * cfg.jitter_std_m
    return targets + noise, targets


def pretrain_pointnet(data: Union[Tensor, CloudSampler], cfg: PointNetConfig, progress: Optional[ProgressFn] = None,
                      device: Optional[Union[str, torch.device]] = None) -> tuple[PointNetEncoder, list[dict]]:
    """Train a :class:`PointNetAutoencoder` with Adam for ``cfg.steps`` steps and return its frozen encoder.

    data: clouds (S, N, 3) sampled on hand / object surfaces in the palm frame (m) -- each step draws
    ``batch_size`` of them with replacement and ``points_per_cloud`` points of each --, or a
    :data:`CloudSampler` returning fresh (batch_size, N, 3) clouds.  device: defaults to the tensor's
    device (CPU for a sampler).  -> (encoder on ``device``, frozen; history: ``{"step", "loss"}`` dicts at
    step 1, every ``log_every`` steps and the last step, loss = minibatch Chamfer distance in scaled units).
    """
    if device is None:
        device = data.device if isinstance(data, Tensor) else torch.device("cpu")
    device = torch.device(device)
    if isinstance(data, Tensor):
        if data.dim() != 3 or data.shape[-1] != 3 or data.shape[0] == 0 or data.shape[1] == 0:
            raise MultigraspError(f"PointNet pretraining data must be clouds of shape (S >= 1, N >= 1, 3), got "
                                  f"{tuple(data.shape)}; pass hand / object surface samples stacked per cloud.")
        data = data.to(device=device, dtype=torch.float32)

    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(cfg.seed)
        model = PointNetAutoencoder(cfg).to(device)
    generator = torch.Generator(device=device).manual_seed(cfg.seed)
    optimizer = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    history: list[dict] = []
    start = time.perf_counter()
    model.train()
    for step in range(1, cfg.steps + 1):
        inputs, targets = _training_pair(data, cfg, generator, device)
        loss = model.loss(inputs, targets)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        if step == 1 or step % cfg.log_every == 0 or step == cfg.steps:
            history.append({"step": step, "loss": loss.item()})
            if progress is not None:
                elapsed = time.perf_counter() - start
                progress(step, cfg.steps, {"loss": history[-1]["loss"], "elapsed_s": elapsed,
                                           "eta_s": elapsed / step * (cfg.steps - step)})
    return model.encoder.freeze(), history


# ---------------------------------------------------------------------------------------------- files


def save_encoder(path: Union[str, Path], encoder: PointNetEncoder, cfg: PointNetConfig) -> Path:
    """Atomically write the encoder's state_dict (on CPU) and ``cfg`` to ``path`` (torch.save). -> path."""
    payload = {"format": _FILE_FORMAT, "version": _FILE_VERSION, "config": cfg.model_dump(mode="json"),
               "state_dict": {k: v.detach().cpu() for k, v in encoder.state_dict().items()}}
    buffer = io.BytesIO()
    torch.save(payload, buffer)
    return atomic_write_bytes(Path(path), buffer.getvalue())


def load_encoder(path: Union[str, Path], device: Union[str, torch.device] = "cpu") -> tuple[PointNetEncoder, PointNetConfig]:
    """Read a file written by :func:`save_encoder`. -> (frozen encoder on ``device``, its config).

    Raises MultigraspError when the file is missing, unreadable or not a matching PointNet encoder.
    """
    path = Path(path)
    fix = "re-run the PointNet pretraining to rewrite it"
    if not path.is_file():
        raise MultigraspError(f"PointNet encoder file {path} not found; run the PointNet pretraining first or fix the path.")
    try:
        payload = torch.load(path, map_location=device, weights_only=True)
    except Exception as exc:  # truncated, not a torch file, unpickling refused ...
        raise MultigraspError(f"PointNet encoder file {path} is corrupt ({type(exc).__name__}); delete it and {fix}.") from exc
    if not isinstance(payload, dict) or payload.get("format") != _FILE_FORMAT or payload.get("version") != _FILE_VERSION:
        raise MultigraspError(f"{path} is not a PointNet encoder file (format {_FILE_FORMAT} v{_FILE_VERSION}); "
                              f"delete it and {fix}.")
    try:
        cfg = PointNetConfig(**payload["config"])
        encoder = PointNetEncoder(cfg)
        encoder.load_state_dict(payload["state_dict"])
    except (KeyError, TypeError, ValidationError, RuntimeError) as exc:
        raise MultigraspError(f"PointNet encoder file {path} does not match its config ({type(exc).__name__}); "
                              f"delete it and {fix}.") from exc
    return encoder.to(device).freeze(), cfg

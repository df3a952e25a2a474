"""PointNet++ object encoder (Qi et al. 2017, "PointNet++"), pure torch: the f_theta(O) of the paper's
§"Multi-object Grasp Generation" that turns each object's point cloud into condition tokens.

One *set abstraction* (SA) level maps points X (N, 3) with features F (N, C) to S centroids:

    1. centroids  c_s = farthest point sampling of X  (s = 1..S)                        (:func:`farthest_point_sampling`)
    2. neighbours N(c_s) = the k nearest points of X within radius r of c_s,
       missing ones padded with the nearest one                                           (:func:`ball_query`)
    3. grouping   g_si = [ (x_i - c_s) / r , F_i ]   for i in N(c_s)                      (:func:`group`)
    4. feature    F'_s = max_{i in N(c_s)} h(g_si),   h a shared MLP                      (:class:`SetAbstraction`)

:class:`PointNet2Encoder` stacks two SA levels and a group-all level, per object:

    tokens (B, n_obj, M, C_tok):  [F''_s, c''_s / scale] of the M = ``sa2_points`` level-2 centroids
                                  (the centroid position is appended: the relative coordinates of the
                                  grouping alone would lose where on the table the token sits),
    global (B, n_obj, C_glob):    max_s h_g([c''_s / scale, F''_s]) over the level-2 tokens.

Every step is invariant to the order of the input points (up to ties): FPS starts from the point
farthest from the cloud's centroid, and the ball query keeps the *nearest* k points in the ball
instead of the first k in memory order.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor, nn

from components.generation.config import GeneratorConfig


# ============================================================================ sampling and grouping
def gather_points(values: Tensor, index: Tensor) -> Tensor:
    """values[b, index[b, ...]]:  values (B, N, C), index (B, *S) long -> (B, *S, C)."""
    batch, channels = values.shape[0], values.shape[-1]
    flat = index.reshape(batch, -1)  # (B, S')
    out = values.gather(1, flat.unsqueeze(-1).expand(-1, -1, channels))  # (B, S', C)
    return out.reshape(*index.shape, channels)


def farthest_point_sampling(points: Tensor, n: int) -> Tensor:
    """Farthest point sampling (greedy k-centre):  i_1 = argmax_i |x_i - mean(X)|,
    i_{s+1} = argmax_i min_{s' <= s} |x_i - x_{i_s'}|.   points (B, N, 3) -> indices (B, n) long.

    The first index is the point farthest from the centroid (not index 0) so the selection does not depend
    on the order of the points.  n <= N."""
    batch, count, _ = points.shape
    if n > count:
        raise ValueError(f"farthest_point_sampling: {n} samples from {count} points")
    rows = torch.arange(batch, device=points.device)
    index = torch.empty(batch, n, dtype=torch.long, device=points.device)
    farthest = (points - points.mean(1, keepdim=True)).square().sum(-1).argmax(-1)  # (B,)
    nearest_sq = torch.full((batch, count), float("inf"), dtype=points.dtype, device=points.device)  # (B, N)
    for s in range(n):
        index[:, s] = farthest
        chosen = points[rows, farthest].unsqueeze(1)  # (B, 1, 3)
        nearest_sq = torch.minimum(nearest_sq, (points - chosen).square().sum(-1))
        farthest = nearest_sq.argmax(-1)
    return index


def ball_query(points: Tensor, centres: Tensor, radius: float, k: int) -> Tensor:
    """Neighbours of each centre:  N(c) = the k nearest points x_i with |x_i - c| <= radius, in order of
    distance; slots beyond the points in the ball (or beyond N) repeat the first (nearest) one.
    points (B, N, 3), centres (B, S, 3) -> indices (B, S, k) long.  A centre taken from ``points`` always has
    itself in its ball."""
    count = points.shape[1]
    dist_sq = torch.cdist(centres, points).square()  # (B, S, N)
    k_eff = min(k, count)
    d_near, index = dist_sq.topk(k_eff, dim=-1, largest=False, sorted=True)  # (B, S, k_eff)
    first = index[..., :1]
    index = torch.where(d_near <= radius * radius, index, first.expand_as(index))
    if k_eff < k:
        index = torch.cat([index, first.expand(*first.shape[:-1], k - k_eff)], dim=-1)
    return index


def group(points: Tensor, features: Tensor | None, centres: Tensor, index: Tensor, radius: float) -> Tensor:
    """Grouped inputs of the shared MLP:  g_si = [(x_i - c_s) / r, F_i]   for i = index[s, :].
    points (B, N, 3), features (B, N, C) or None, centres (B, S, 3), index (B, S, k) -> (B, S, k, 3 + C)."""
    rel = (gather_points(points, index) - centres.unsqueeze(2)) / radius  # (B, S, k, 3)
    if features is None:
        return rel
    return torch.cat([rel, gather_points(features, index)], dim=-1)


def shared_mlp(c_in: int, widths: Sequence[int]) -> nn.Sequential:
    """Per-point MLP h: Linear -> LayerNorm -> ReLU for every width (applied on the last axis)."""
    layers: list[nn.Module] = []
    for c_out in widths:
        layers += [nn.Linear(c_in, c_out), nn.LayerNorm(c_out), nn.ReLU()]
        c_in = c_out
    return nn.Sequential(*layers)


# ============================================================================ levels
class SetAbstraction(nn.Module):
    """One SA level (module docstring, steps 1-4):  (B, N, 3), (B, N, C) -> (B, S, 3), (B, S, C')."""

    def __init__(self, n_centres: int, radius: float, k: int, c_in: int, widths: Sequence[int]):
        super().__init__()
        self.n_centres, self.radius, self.k = n_centres, radius, k
        self.mlp = shared_mlp(3 + c_in, widths)
        self.out_dim = widths[-1]

    def forward(self, points: Tensor, features: Tensor | None) -> tuple[Tensor, Tensor]:
        centre_index = farthest_point_sampling(points, self.n_centres)  # (B, S)
        centres = gather_points(points, centre_index)  # (B, S, 3)
        neighbours = ball_query(points, centres, self.radius, self.k)  # (B, S, k)
        grouped = group(points, features, centres, neighbours, self.radius)  # (B, S, k, 3 + C)
        return centres, self.mlp(grouped).amax(dim=2)  # (B, S, 3), (B, S, C')


class PointNet2Encoder(nn.Module):
    """Two SA levels + group-all, per object:  clouds (B, n_obj, N, 3) (m) ->
    tokens (B, n_obj, M, ``token_dim``), global (B, n_obj, ``global_dim``) (module docstring)."""

    def __init__(self, cfg: GeneratorConfig):
        super().__init__()
        self.scale = cfg.input_scale_m
        self.sa1 = SetAbstraction(cfg.sa1_points, cfg.sa1_radius_m / cfg.input_scale_m, cfg.sa1_neighbours, 0, cfg.sa1_widths)
        self.sa2 = SetAbstraction(cfg.sa2_points, cfg.sa2_radius_m / cfg.input_scale_m, cfg.sa2_neighbours,
                                  self.sa1.out_dim, cfg.sa2_widths)
        self.token_dim = self.sa2.out_dim + 3
        self.global_mlp = shared_mlp(self.token_dim, cfg.global_widths)
        self.global_dim = cfg.global_widths[-1]

    def forward(self, clouds: Tensor) -> tuple[Tensor, Tensor]:
        batch, n_obj, count, _ = clouds.shape
        points = clouds.reshape(batch * n_obj, count, 3) / self.scale  # (B', N, 3), B' = B n_obj
        xyz1, feat1 = self.sa1(points, None)  # (B', S1, 3), (B', S1, C1)
        xyz2, feat2 = self.sa2(xyz1, feat1)  # (B', M, 3), (B', M, C2)
        tokens = torch.cat([feat2, xyz2], dim=-1)  # (B', M, C2 + 3)
        global_feature = self.global_mlp(tokens).amax(dim=1)  # (B', C_glob)
        return (tokens.reshape(batch, n_obj, *tokens.shape[1:]),
                global_feature.reshape(batch, n_obj, -1))

"""Noise-prediction network eps_theta(H^(t), t, f_theta(O)) of the grasp generator (paper §"Multi-object
Grasp Generation", after SceneDiffuser; DESIGN §5.2).  With ``prediction='v'`` the same network is trained to
output v instead (diffusion module docstring); nothing here changes.

* **Hand tokens.**  The (normalised) hand representation x_t (B, D) is cut into ``n_tokens`` tokens of
  ``token_dim`` numbers: 31 tokens of 3 for the keypoint representation (one token per keypoint, so
  attention can relate single finger links to object parts), one token of 31 for (p, rot6d, q).
  h_k = W_in x_k + e_k (learnable token embedding e_k).
* **Time.**  Sinusoidal embedding  emb(t)_i = sin(t w_i), emb(t)_{i + d/2} = cos(t w_i),
  w_i = 10000^(-i / (d/2 - 1))  (:func:`timestep_embedding`), then an MLP; each block adds a projection of it.
* **Objects.**  :class:`~components.generation.pointnet2.PointNet2Encoder` gives per object M tokens and a
  global token; both are projected to ``model_dim`` and, with ``use_object_embedding``, the learnable
  embedding s_j of object slot j is added to every token of object j (identical within an object,
  different across objects).  Absent objects (``object_mask`` False) are masked out of the attention.
* **Blocks** (pre-LayerNorm):  h += SelfAttn(LN h);  h += CrossAttn(q = LN h, k = v = object tokens);
  h += MLP(LN h).  Output: W_out LN(h) per token, flattened back to (B, D).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Union

import torch
from torch import Tensor, nn

from components.generation.config import GeneratorConfig
from components.generation.pointnet2 import PointNet2Encoder


def timestep_embedding(t: Tensor, dim: int, max_period: float = 10000.0) -> Tensor:
    """Sinusoidal embedding (Vaswani et al. 2017; DDPM):  [sin(t w_i), cos(t w_i)]_{i < dim/2},
    w_i = max_period^(-i / (dim/2 - 1)).   t (B,) -> (B, dim)."""
    half = dim // 2
    freqs = torch.exp(-math.log(max_period) * torch.arange(half, device=t.device, dtype=torch.float32) / max(half - 1, 1))
    angles = t.float().unsqueeze(-1) * freqs  # (B, half)
    return torch.cat([angles.sin(), angles.cos()], dim=-1)


@dataclass
class ObjectInputs:
    """Raw condition: object clouds (B, n_obj, N, 3) in the palm-aligned frame (m) and which slots hold an
    object (B, n_obj) bool (None = all)."""

    clouds: Tensor
    mask: Optional[Tensor] = None


@dataclass
class ObjectContext:
    """Encoded condition: tokens (B, T_obj, model_dim) and the attention padding mask (B, T_obj) bool
    (True = ignore), T_obj = n_obj (M + 1).  ``keys_values``: optional per-block cross-attention keys and
    values of the tokens, (B, heads, T_obj, head_dim) each (:meth:`GraspDenoiser.cache_keys_values`)."""

    tokens: Tensor
    padding: Tensor
    keys_values: Optional[list[tuple[Tensor, Tensor]]] = None

    def repeat_interleave(self, repeats: int) -> "ObjectContext":
        """Each scene's context ``repeats`` times in a row: (B, ...) -> (B repeats, ...) (several grasps per scene)."""
        kv = None if self.keys_values is None else [(k.repeat_interleave(repeats, 0), v.repeat_interleave(repeats, 0))
                                                    for k, v in self.keys_values]
        return ObjectContext(self.tokens.repeat_interleave(repeats, 0), self.padding.repeat_interleave(repeats, 0), kv)


class DenoiserBlock(nn.Module):
    """h += time projection; h += SelfAttn(LN h); h += CrossAttn(LN h, objects); h += MLP(LN h)."""

    def __init__(self, dim: int, heads: int, mlp_ratio: int, dropout: float):
        super().__init__()
        self.time = nn.Linear(dim, dim)
        self.norm_self, self.norm_cross, self.norm_mlp = nn.LayerNorm(dim), nn.LayerNorm(dim), nn.LayerNorm(dim)
        self.self_attn = nn.MultiheadAttention(dim, heads, dropout=dropout, batch_first=True)
        self.cross_attn = nn.MultiheadAttention(dim, heads, dropout=dropout, batch_first=True)
        self.mlp = nn.Sequential(nn.Linear(dim, mlp_ratio * dim), nn.GELU(), nn.Dropout(dropout),
                                 nn.Linear(mlp_ratio * dim, dim))

    def keys_values(self, tokens: Tensor) -> tuple[Tensor, Tensor]:
        """The cross-attention's keys and values of object tokens (B, T, dim), split into heads:
        k = tokens W_k^T + b_k, v = tokens W_v^T + b_v (``cross_attn``'s own in-projection).  -> 2 x (B, heads, T, dim / heads)."""
        attn, dim = self.cross_attn, tokens.shape[-1]
        weight, bias = attn.in_proj_weight, attn.in_proj_bias
        k = nn.functional.linear(tokens, weight[dim:2 * dim], bias[dim:2 * dim])
        v = nn.functional.linear(tokens, weight[2 * dim:], bias[2 * dim:])
        split = lambda x: x.unflatten(-1, (attn.num_heads, dim // attn.num_heads)).transpose(1, 2)  # noqa: E731
        return split(k), split(v)

    def cached_cross_attention(self, x: Tensor, keys: Tensor, values: Tensor, padding: Tensor) -> Tensor:
        """``cross_attn(x, tokens, tokens, key_padding_mask=padding)`` from pre-computed keys and values
        (eval mode: no dropout).  x (B, K, dim) -> (B, K, dim)."""
        attn, dim = self.cross_attn, x.shape[-1]
        q = nn.functional.linear(x, attn.in_proj_weight[:dim], attn.in_proj_bias[:dim])
        q = q.unflatten(-1, (attn.num_heads, dim // attn.num_heads)).transpose(1, 2)  # (B, heads, K, head_dim)
        out = nn.functional.scaled_dot_product_attention(q, keys, values, attn_mask=~padding[:, None, None, :])
        return attn.out_proj(out.transpose(1, 2).flatten(2))

    def forward(self, h: Tensor, time: Tensor, context: ObjectContext, index: int = 0) -> Tensor:
        """h (B, K, dim), time (B, dim) -> (B, K, dim).  ``index``: this block's entry of ``context.keys_values``."""
        h = h + self.time(time).unsqueeze(1)
        x = self.norm_self(h)
        h = h + self.self_attn(x, x, x, need_weights=False)[0]
        x = self.norm_cross(h)
        if context.keys_values is not None and not self.training:
            keys, values = context.keys_values[index]
            h = h + self.cached_cross_attention(x, keys, values, context.padding)
        else:
            h = h + self.cross_attn(x, context.tokens, context.tokens, key_padding_mask=context.padding,
                                    need_weights=False)[0]
        return h + self.mlp(self.norm_mlp(h))


class GraspDenoiser(nn.Module):
    """eps_theta(x_t (B, n_tokens token_dim), t (B,), objects) -> (B, n_tokens token_dim) (module docstring)."""

    def __init__(self, cfg: GeneratorConfig, n_tokens: int, token_dim: int):
        super().__init__()
        dim = cfg.model_dim
        self.cfg, self.n_tokens, self.token_dim = cfg, n_tokens, token_dim
        # objects
        self.encoder = PointNet2Encoder(cfg)
        self.object_proj = nn.Linear(self.encoder.token_dim, dim)
        self.global_proj = nn.Linear(self.encoder.global_dim, dim)
        self.slot_embedding = nn.Parameter(0.02 * torch.randn(cfg.max_objects, dim)) if cfg.use_object_embedding else None
        # hand
        self.token_in = nn.Linear(token_dim, dim)
        self.token_embedding = nn.Parameter(0.02 * torch.randn(n_tokens, dim))
        self.time_mlp = nn.Sequential(nn.Linear(cfg.time_embedding_dim, dim), nn.SiLU(), nn.Linear(dim, dim))
        self.blocks = nn.ModuleList(DenoiserBlock(dim, cfg.heads, cfg.mlp_ratio, cfg.dropout) for _ in range(cfg.blocks))
        self.norm_out = nn.LayerNorm(dim)
        self.token_out = nn.Linear(dim, token_dim)

    @classmethod
    def for_representation(cls, cfg: GeneratorConfig) -> "GraspDenoiser":
        """31 tokens of 3 (keypoints) or 1 token of 31 (p, rot6d, q)."""
        return cls(cfg, 31, 3) if cfg.representation == "keypoints" else cls(cfg, 1, 31)

    @property
    def dim(self) -> int:
        """D = n_tokens token_dim, the flat size of the hand representation."""
        return self.n_tokens * self.token_dim

    def encode(self, objects: ObjectInputs) -> ObjectContext:
        """PointNet++ tokens + global token of each object, projected, plus the slot embedding (module docstring).
        clouds (B, n_obj, N, 3) -> ObjectContext with tokens (B, n_obj (M + 1), model_dim)."""
        clouds = objects.clouds
        batch, n_obj = clouds.shape[:2]
        if n_obj > self.cfg.max_objects:
            raise ValueError(f"{n_obj} objects but generator.max_objects = {self.cfg.max_objects}")
        local, global_feature = self.encoder(clouds)  # (B, n_obj, M, C_tok), (B, n_obj, C_glob)
        tokens = torch.cat([self.global_proj(global_feature).unsqueeze(2), self.object_proj(local)], dim=2)  # (B, n_obj, M+1, dim)
        if self.slot_embedding is not None:
            tokens = tokens + self.slot_embedding[:n_obj].reshape(1, n_obj, 1, -1)
        mask = objects.mask if objects.mask is not None else torch.ones(batch, n_obj, dtype=torch.bool, device=clouds.device)
        padding = (~mask.bool()).unsqueeze(-1).expand(-1, -1, tokens.shape[2])  # (B, n_obj, M+1)
        return ObjectContext(tokens.reshape(batch, -1, tokens.shape[-1]), padding.reshape(batch, -1))

    def cache_keys_values(self, context: ObjectContext) -> ObjectContext:
        """The context with every block's cross-attention keys and values computed once: the sampler calls
        the denoiser T = 100 times on the same objects, and projecting the object tokens at every call cost
        ~a fifth of a sampling step (B = 256, CPU).  Same outputs (tested)."""
        with torch.no_grad():
            kv = [block.keys_values(context.tokens) for block in self.blocks]
        return ObjectContext(context.tokens, context.padding, kv)

    def forward(self, x_t: Tensor, t: Tensor, cond: Union[ObjectInputs, ObjectContext]) -> Tensor:
        """Predicted noise (B, D).  ``cond`` is encoded here when it is raw :class:`ObjectInputs` (training);
        the sampler passes a pre-encoded :class:`ObjectContext`."""
        context = self.encode(cond) if isinstance(cond, ObjectInputs) else cond
        batch = x_t.shape[0]
        h = self.token_in(x_t.reshape(batch, self.n_tokens, self.token_dim)) + self.token_embedding  # (B, K, dim)
        time = self.time_mlp(timestep_embedding(t, self.cfg.time_embedding_dim).to(x_t.dtype))  # (B, dim)
        for index, block in enumerate(self.blocks):
            h = block(h, time, context, index)
        return self.token_out(self.norm_out(h)).reshape(batch, -1)

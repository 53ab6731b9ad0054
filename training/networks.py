"""Actor and critic MLPs and the running observation normaliser (PyTorch).

The actor maps a (normalised) observation to an action in [-1, 1]^2 through tanh; the critic maps an observation
and an action to one Q value. ``RunningNorm`` keeps its statistics as registered buffers, so they travel with the
module's ``state_dict`` into checkpoints and exported policies.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from torch import nn


def mlp(sizes: Sequence[int], out_activation: nn.Module | None = None) -> nn.Sequential:
    """Linear layers with ReLU between them; ``out_activation`` after the last one if given."""
    layers: list[nn.Module] = []
    for i in range(len(sizes) - 1):
        layers.append(nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2:
            layers.append(nn.ReLU())
    if out_activation is not None:
        layers.append(out_activation)
    return nn.Sequential(*layers)


class RunningNorm(nn.Module):
    """Observation normaliser: (x - mean) / sqrt(var + eps), clipped to +-``clip``; identity when disabled.

    Statistics are updated from collected observations with Chan's parallel algorithm (``update``), never from
    replayed batches.
    """

    def __init__(self, dim: int, enabled: bool = True, clip: float = 10.0, eps: float = 1e-8) -> None:
        super().__init__()
        self.enabled = enabled
        self.clip = clip
        self.eps = eps
        self.register_buffer("mean", torch.zeros(dim, dtype=torch.float64))
        self.register_buffer("var", torch.ones(dim, dtype=torch.float64))
        self.register_buffer("count", torch.tensor(1e-4, dtype=torch.float64))

    def update(self, x: np.ndarray) -> None:
        """Fold a batch of observations (n, dim) into the statistics."""
        if not self.enabled or len(x) == 0:
            return
        x = torch.as_tensor(np.asarray(x, dtype=np.float64))
        b_mean, b_var, b_n = x.mean(0), x.var(0, unbiased=False), float(len(x))
        delta = b_mean - self.mean
        total = self.count + b_n
        self.mean += delta * b_n / total
        m2 = self.var * self.count + b_var * b_n + delta.square() * self.count * b_n / total
        self.var.copy_(m2 / total)
        self.count.copy_(total)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not self.enabled:
            return x
        std = torch.sqrt(self.var + self.eps).to(x.dtype)
        return torch.clamp((x - self.mean.to(x.dtype)) / std, -self.clip, self.clip)


class Actor(nn.Module):
    """mu(s): observation -> action in [-1, 1]^act_dim."""

    def __init__(self, obs_dim: int, act_dim: int, hidden: Sequence[int]) -> None:
        super().__init__()
        self.net = mlp([obs_dim, *hidden, act_dim], nn.Tanh())

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.net(obs)


class Critic(nn.Module):
    """Q(s, a): one or two (TD3's twin) Q heads over the concatenated observation and action."""

    def __init__(self, obs_dim: int, act_dim: int, hidden: Sequence[int], n_heads: int = 1) -> None:
        super().__init__()
        self.heads = nn.ModuleList(mlp([obs_dim + act_dim, *hidden, 1]) for _ in range(n_heads))

    def forward(self, obs: torch.Tensor, action: torch.Tensor) -> list[torch.Tensor]:
        """Every head's Q values, each (B,)."""
        x = torch.cat([obs, action], dim=-1)
        return [h(x).squeeze(-1) for h in self.heads]

"""Actor and critic networks and the running observation normaliser (PyTorch).

The actor maps a (normalised) observation to an action in [-1, 1]^2 through tanh: an MLP over the flat vector
(``Actor``) or one shared encoder per set of obstacles, max-pooled, under an MLP head (``SetActor``); the critic
maps an observation and an action to one Q value. ``RunningNorm`` keeps its statistics as registered buffers, so
they travel with the module's ``state_dict`` into checkpoints and exported policies.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import torch
from torch import nn

from deck_sim.policies import set_indices


class MLP(nn.Sequential):
    """``nn.Sequential`` whose last linear layer runs in float32 under a bfloat16 autocast: the hidden layers'
    matrix products take the fast path, while the outputs (Q values, actions, a set encoder's features) keep
    float32's resolution. Without autocast it is ``nn.Sequential``'s forward, the same numbers."""

    def __init__(self, *layers: nn.Module) -> None:
        super().__init__(*layers)
        self._last_linear = max(i for i, m in enumerate(layers) if isinstance(m, nn.Linear))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not torch.is_autocast_enabled("cpu"):
            return super().forward(x)
        x = self.linear_out(x)
        for layer in list(self)[self._last_linear + 1:]:
            x = layer(x)
        return x

    def linear_out(self, x: torch.Tensor) -> torch.Tensor:
        """The last linear layer's output, before the output activation (an actor's pre-tanh action)."""
        autocast = torch.is_autocast_enabled("cpu")
        for i, layer in enumerate(self):
            if i > self._last_linear:
                break
            if i == self._last_linear and autocast:
                with torch.autocast("cpu", enabled=False):
                    x = layer(x.float())
            else:
                x = layer(x)
        return x


def mlp(sizes: Sequence[int], out_activation: nn.Module | None = None, layer_norm: bool = False) -> MLP:
    """Linear layers with ReLU between them; with ``layer_norm`` a ``LayerNorm`` after each hidden layer's linear map
    (before its ReLU); ``out_activation`` after the last one if given."""
    layers: list[nn.Module] = []
    for i in range(len(sizes) - 1):
        layers.append(nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2:
            if layer_norm:
                layers.append(nn.LayerNorm(sizes[i + 1]))
            layers.append(nn.ReLU())
    if out_activation is not None:
        layers.append(out_activation)
    return MLP(*layers)


class RunningNorm(nn.Module):
    """Observation normaliser: (x - mean) / sqrt(var + eps), clipped to +-``clip``; identity when disabled.

    Statistics are updated from collected observations with Chan's parallel algorithm (``update``), never from
    replayed batches. Each dimension keeps its own count, so that entries which stand for nothing (the rows of the
    movers a curriculum stage leaves out, ``training.envs.ObservationLayout.real_mask``) can be left out of it.
    """

    def __init__(self, dim: int, enabled: bool = True, clip: float = 10.0, eps: float = 1e-8) -> None:
        super().__init__()
        self.enabled = enabled
        self.clip = clip
        self.eps = eps
        self.register_buffer("mean", torch.zeros(dim, dtype=torch.float64))
        self.register_buffer("var", torch.ones(dim, dtype=torch.float64))
        self.register_buffer("count", torch.full((dim,), 1e-4, dtype=torch.float64))
        self._groups: list[torch.Tensor] = []  # index arrays whose rows share statistics (``tie``)
        self._uniform = True  # every dimension has the same count (no masked entry yet)

    def _load_from_state_dict(self, state_dict: Mapping, prefix: str, *args: object, **kwargs: object) -> None:
        count = state_dict.get(prefix + "count")
        if isinstance(count, torch.Tensor) and count.dim() == 0:  # one count for every dimension (older files)
            state_dict = {**state_dict, prefix + "count": count.expand_as(self.count).clone()}
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)
        self._uniform = bool(torch.all(self.count == self.count[:1]))

    def update(self, x: np.ndarray, valid: np.ndarray | None = None) -> None:
        """Fold a batch of observations (n, dim) into the statistics; with ``valid`` (n, dim) booleans, each
        dimension only from the entries marked True (a dimension with none keeps its statistics)."""
        if not self.enabled or len(x) == 0:
            return
        x = torch.as_tensor(np.asarray(x, dtype=np.float64))
        if valid is None or bool(np.all(valid)):
            b_mean, b_var, b_n = x.mean(0), x.var(0, unbiased=False), torch.full_like(self.count, float(len(x)))
        else:
            keep = torch.as_tensor(np.asarray(valid, dtype=bool))
            b_n = keep.sum(0).to(torch.float64)
            seen = b_n > 0
            zero = torch.zeros((), dtype=torch.float64)
            b_mean = torch.where(seen, torch.where(keep, x, zero).sum(0) / b_n.clamp_min(1.0), self.mean)
            b_var = torch.where(seen, torch.where(keep, (x - b_mean).square(), zero).sum(0) / b_n.clamp_min(1.0),
                                self.var)
            self._uniform = False
        delta = b_mean - self.mean
        total = self.count + b_n
        self.mean += delta * b_n / total
        m2 = self.var * self.count + b_var * b_n + delta.square() * self.count * b_n / total
        self.var.copy_(m2 / total)
        self.count.copy_(total)
        if not self._uniform:
            self._uniform = bool(torch.all(self.count == self.count[:1]))

    def tie(self, groups: Sequence[np.ndarray]) -> None:
        """Normalise each group's rows alike: ``groups`` are index arrays (n, f) whose n rows are the same f
        features of n obstacles (``deck_sim.policies.set_indices``); each feature is then normalised by its mean
        and variance over all n rows together, so a shared set encoder reads the same metres the same way in every
        row. The statistics kept are unchanged (``stats`` pools them)."""
        self._groups = [torch.as_tensor(np.asarray(g, dtype=np.int64)) for g in groups if np.size(g)]

    def stats(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The (mean, std) that ``forward`` applies, float64 (dim,): per dimension, pooled over tied groups."""
        if not self._groups:  # (the MLP actor's case: nothing to pool, nothing copied)
            return self.mean, torch.sqrt(self.var + self.eps)
        mean, var = self.mean.clone(), self.var.clone()
        for g in self._groups:
            m, v, n = self.mean[g], self.var[g], self.count[g]  # (n, f)
            if self._uniform or bool(torch.all(n == n[:1])):  # every row saw the same count
                pooled = m.mean(0)
                var[g] = ((v + m.square()).mean(0) - pooled.square()).clamp_min(0.0).expand_as(m)
            else:  # (rows a curriculum stage left out saw fewer): each row weighs by its count
                w = n / n.sum(0)
                pooled = (w * m).sum(0)
                var[g] = ((w * (v + m.square())).sum(0) - pooled.square()).clamp_min(0.0).expand_as(m)
            mean[g] = pooled.expand_as(m)
        return mean, torch.sqrt(var + self.eps)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not self.enabled:
            return x
        mean, std = self.stats()
        return torch.clamp((x - mean.to(x.dtype)) / std.to(x.dtype), -self.clip, self.clip)


class Actor(nn.Module):
    """mu(s): observation -> action in [-1, 1]^act_dim."""

    def __init__(self, obs_dim: int, act_dim: int, hidden: Sequence[int]) -> None:
        super().__init__()
        self.net = mlp([obs_dim, *hidden, act_dim], nn.Tanh())

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.net(obs)

    def preactivation(self, obs: torch.Tensor) -> torch.Tensor:
        """The action before its tanh: ``forward(obs) == tanh(preactivation(obs))``."""
        return self.net.linear_out(obs)


class SetActor(nn.Module):
    """mu(s) with one encoder per set of obstacles (Deep Sets; Zaheer et al., 2017), as in crowd navigation's
    pooled pairwise features (Chen et al., 2019, SARL).

    Each obstacle's features (its rows of the set's keys: a mover's position now, forecast and size) beside the
    context (every key in no set: target, own position, velocity, heading...) pass through the set's shared MLP
    (``set_hidden``, ReLU after every layer) and are max-pooled over the set's obstacles; the head MLP
    (``hidden``) maps the context and each set's pooled features to the action through tanh. One weight set
    serves every mover, so what is learnt about one mover's forecast holds for all of them, whichever slot of
    the nearest-first order it is in. ``deck_sim.policies.LearnedPolicy`` runs the exported arrays
    (``deck_sim.actor/3``).

    Args:
        shapes: the flat observation's keys and shapes, in order.
        sets: set name -> its keys (``deck_sim.policies.obstacle_sets``).
    """

    def __init__(
        self,
        shapes: Mapping[str, Sequence[int]],
        sets: Mapping[str, Sequence[str]],
        act_dim: int,
        hidden: Sequence[int],
        set_hidden: Sequence[int],
    ) -> None:
        super().__init__()
        context, elements = set_indices(shapes, sets)
        self.register_buffer("context", torch.as_tensor(context), persistent=False)
        self.names = list(elements)
        for name, idx in elements.items():
            self.register_buffer(f"idx_{name}", torch.as_tensor(idx), persistent=False)
        c = len(context)
        self.encoders = nn.ModuleDict(
            {name: mlp([idx.shape[1] + c, *set_hidden], nn.ReLU()) for name, idx in elements.items()}
        )
        self.head = mlp([c + len(elements) * int(set_hidden[-1]), *hidden, act_dim], nn.Tanh())

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.head(self._head_input(obs))

    def preactivation(self, obs: torch.Tensor) -> torch.Tensor:
        """The action before its tanh: ``forward(obs) == tanh(preactivation(obs))``."""
        return self.head.linear_out(self._head_input(obs))

    def _head_input(self, obs: torch.Tensor) -> torch.Tensor:
        context = obs[..., self.context]
        parts = [context]
        for name in self.names:
            elements = obs[..., getattr(self, f"idx_{name}")]  # (..., n, f)
            ctx = context.unsqueeze(-2).expand(*elements.shape[:-1], context.shape[-1])
            encoded = self.encoders[name](torch.cat([elements, ctx], dim=-1))
            parts.append(pool(encoded))
        return torch.cat(parts, dim=-1)


def pool(encoded: torch.Tensor) -> torch.Tensor:
    """The maximum over the obstacles' axis (-2) of a set's encoded rows. Without a gradient to keep, ``amax``
    (the values alone, the same numbers); otherwise ``max``, whose backward sends each column's gradient to its
    first maximum."""
    if torch.is_grad_enabled() and encoded.requires_grad:
        return encoded.max(dim=-2).values
    return encoded.amax(dim=-2)


class Critic(nn.Module):
    """Q(s, a): one or two (TD3's twin) Q heads over the concatenated observation and action; with ``layer_norm``
    each hidden layer is normalised (``mlp``), as in the critics of DroQ and RLPD."""

    def __init__(self, obs_dim: int, act_dim: int, hidden: Sequence[int], n_heads: int = 1,
                 layer_norm: bool = False) -> None:
        super().__init__()
        self.heads = nn.ModuleList(mlp([obs_dim + act_dim, *hidden, 1], layer_norm=layer_norm)
                                   for _ in range(n_heads))

    def forward(self, obs: torch.Tensor, action: torch.Tensor) -> list[torch.Tensor]:
        """Every head's Q values, each (B,)."""
        x = torch.cat([obs, action], dim=-1)
        return [h(x).squeeze(-1) for h in self.heads]

    def first(self, obs: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """The first head's Q values (B,), the one the actor's loss reads (the same numbers as ``forward``'s
        first)."""
        return self.heads[0](torch.cat([obs, action], dim=-1)).squeeze(-1)

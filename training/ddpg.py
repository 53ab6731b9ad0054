"""DDPG (paper eq. 3-6) with TD3's fixes and DDPGfD's demonstration loss as switches of one agent.

- eq. 3: y = r if terminated else r + gamma * Q'(s', mu'(s'))  (TD3: the minimum of two target critics, or a
  weighted mean of the smaller and the larger, and clipped noise on mu'(s'); an n-step batch brings its summed r
  and its own gamma^m);
- eq. 4: critic loss, mean squared error to y (summed over the twin critics);
- eq. 5: actor loss -mean Q(s, mu(s)), plus ``bc_weight`` times the squared error to the demonstrator's action on
  the samples that have one (demonstrations, and the agent's own states relabelled by the planner online), where
  the critic prefers the demonstrator's action (the Q-filter);
- eq. 6: theta' <- tau theta + (1 - tau) theta' for the actor and the critics (``soft_update``).
With every switch off this is the paper's DDPG.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import torch
from torch import nn

from deck_sim.policies import ACTOR_FORMAT, ACTOR_FORMAT_SETS, CRITIC_PREFIX, obstacle_sets, set_indices
from training.buffers import Batch
from training.config import TrainConfig
from training.networks import Actor, Critic, RunningNorm, SetActor


@torch.no_grad()
def soft_update(target: nn.Module, source: nn.Module, tau: float) -> None:
    """theta' <- tau theta + (1 - tau) theta' for every parameter (eq. 6), in two fused multi-tensor ops;
    buffers are copied."""
    targets, sources = list(target.parameters()), list(source.parameters())
    if len(targets) != len(sources):
        raise ValueError(f"target has {len(targets)} parameters, source {len(sources)}")
    torch._foreach_mul_(targets, 1.0 - tau)
    torch._foreach_add_(targets, sources, alpha=tau)
    for t, s in zip(target.buffers(), source.buffers(), strict=True):
        t.copy_(s)


class Acting:
    """The greedy policy of an observation normaliser and an actor: actions (n, act_dim) float64 in [-1, 1] for
    raw observations (n, obs_dim), one batched forward pass. It holds the modules themselves: the learner's live
    ones, or a pickled copy in a rollout worker (``training.runners``), which acts exactly as they did."""

    def __init__(self, norm: RunningNorm, actor: nn.Module) -> None:
        self.norm = norm
        self.actor = actor

    @torch.no_grad()
    def __call__(self, obs: np.ndarray) -> np.ndarray:
        x = torch.as_tensor(np.asarray(obs, dtype=np.float32))
        return self.actor(self.norm(x)).numpy().astype(np.float64)


class DDPGAgent:
    """Actor, critic(s), their targets, optimisers and the observation normaliser.

    Args:
        obs_dim, act_dim: sizes of the flat observation and of the action.
        config: the run's hyperparameters (networks, learning rates, gamma, tau and the switches).
        generator: the torch generator for target smoothing noise (seeded by the trainer).
        shapes: the flat observation's keys and shapes in order; needed by ``actor_arch = "sets"``, whose actor
            reads the obstacles' rows (``deck_sim.policies.obstacle_sets``) and whose normaliser then pools each
            set's statistics over its obstacles (``RunningNorm.tie``).
    """

    def __init__(
        self,
        obs_dim: int,
        act_dim: int,
        config: TrainConfig,
        generator: torch.Generator | None = None,
        shapes: Mapping[str, Sequence[int]] | None = None,
    ):
        self.config = config
        self.obs_dim, self.act_dim = obs_dim, act_dim
        hidden = tuple(config.hidden)
        self.norm = RunningNorm(obs_dim, enabled=config.obs_norm)
        self.sets: dict[str, list[str]] = {}
        self.shapes = {k: tuple(int(n) for n in v) for k, v in (shapes or {}).items()}
        if config.actor_arch == "sets":
            if not self.shapes or sum(int(np.prod(v)) for v in self.shapes.values()) != obs_dim:
                raise ValueError(f"actor_arch 'sets' needs the observation's shapes summing to {obs_dim} inputs, "
                                 f"got {self.shapes or None}")
            self.sets = obstacle_sets(self.shapes)
            if not self.sets:
                raise ValueError(f"actor_arch 'sets': the observation {sorted(self.shapes)} holds no obstacle set")
            self.norm.tie(list(set_indices(self.shapes, self.sets)[1].values()))
        self.actor_avg: nn.Module | None = None
        """The slow Polyak average of the actor (``config.actor_average``; None when off)."""
        self.set_actor_widths(hidden)  # the actor, its target and its optimiser (initialised before the critic)
        if config.actor_average:
            self.actor_avg = copy.deepcopy(self.actor)
            for p in self.actor_avg.parameters():
                p.requires_grad_(False)
        self.critic = Critic(obs_dim, act_dim, hidden, n_heads=2 if config.twin_critics else 1,
                             layer_norm=config.critic_layer_norm)
        self.critic_target = copy.deepcopy(self.critic)
        for p in self.critic_target.parameters():
            p.requires_grad_(False)
        # fused Adam: one kernel per step for all parameters
        self.critic_opt = torch.optim.Adam(self.critic.parameters(), lr=config.critic_lr, fused=True)
        self.generator = generator if generator is not None else torch.Generator().manual_seed(0)
        self.updates = 0
        self.bc_weight = float(config.bc_weight)
        """The cloning weight of the next actor updates (the trainer follows ``bc_weight_final``'s schedule)."""

    # -- acting ---------------------------------------------------------------------------------------------
    def act(self, obs: np.ndarray) -> np.ndarray:
        """Greedy actions (n, act_dim) in [-1, 1] for raw observations (n, obs_dim), one batched forward pass."""
        return self.acting()(obs)

    def acting(self) -> Acting:
        """The greedy policy as it stands (the live normaliser and actor; a runner copies them where it acts
        elsewhere)."""
        return Acting(self.norm, self.actor)

    # -- learning -------------------------------------------------------------------------------------------
    @torch.no_grad()
    def td_target(self, batch: Batch) -> torch.Tensor:
        """y of eq. 3 for every transition of ``batch`` (B,)."""
        cfg = self.config
        next_obs = self.norm(batch.next_obs)
        next_action = self.actor_target(next_obs)
        if cfg.target_noise > 0.0:
            eps = torch.randn(next_action.shape, generator=self.generator) * cfg.target_noise
            next_action = (next_action + eps.clamp(-cfg.target_noise_clip, cfg.target_noise_clip)).clamp(-1.0, 1.0)
        q_next = self.combine_heads(torch.stack(self.critic_target(next_obs, next_action)))
        discount = cfg.gamma if batch.discount is None else batch.discount  # (an n-step batch's own gamma^m)
        return cfg.reward_scale * batch.reward + discount * (1.0 - batch.terminated) * q_next

    def combine_heads(self, heads: torch.Tensor) -> torch.Tensor:
        """The TD target's value estimate (B,) from the critic heads' Q values stacked (n_heads, B): one head's own,
        TD3's minimum of two, or ``twin_min_weight`` times the smaller plus the rest times the larger."""
        q = heads.min(dim=0).values
        w = self.config.twin_min_weight
        if len(heads) > 1 and w < 1.0:
            q = w * q + (1.0 - w) * heads.max(dim=0).values
        return q

    def precision(self) -> torch.autocast:
        """The context the updates run in: a bfloat16 CPU autocast under ``learner_precision = "bfloat16"``
        (``training.networks.MLP`` keeps every output layer in float32), a disabled one otherwise."""
        return torch.autocast("cpu", dtype=torch.bfloat16, enabled=self.config.learner_precision == "bfloat16")

    def update(self, batch: Batch, clone_only: bool = False) -> dict[str, float]:
        """One critic update, and (every ``policy_delay`` updates) one actor update and soft target updates, in the
        arithmetic of ``learner_precision`` (``precision``).

        ``clone_only`` (pre-training on demonstrations) updates the actor by the cloning term alone.

        Returns the update's statistics: ``critic_loss``, ``q`` (mean Q of the batch's actions) and, when the actor
        was updated, ``actor_loss``, ``bc_loss`` and ``bc_share`` (the share of demonstration samples cloned).
        The first critic's TD errors of the batch (B,) are left in ``last_td_error`` (prioritised replay's
        priorities).
        """
        with self.precision():
            return self._update(batch, clone_only)

    def _update(self, batch: Batch, clone_only: bool) -> dict[str, float]:
        cfg = self.config
        y = self.td_target(batch)
        obs = self.norm(batch.obs)
        qs = self.critic(obs, batch.action)
        if batch.weight is None:
            critic_loss = sum(torch.mean((q - y) ** 2) for q in qs)
        else:  # prioritised replay: each squared error by its importance-sampling weight
            critic_loss = sum(torch.mean(batch.weight * (q - y) ** 2) for q in qs)
        self.last_td_error = (qs[0] - y).detach().numpy()
        self.critic_opt.zero_grad(set_to_none=True)
        critic_loss.backward()
        if cfg.grad_clip > 0:
            nn.utils.clip_grad_norm_(self.critic.parameters(), cfg.grad_clip)
        self.critic_opt.step()
        self.updates += 1
        stats = {"critic_loss": critic_loss.item(), "q": qs[0].detach().mean().item()}
        if self.updates % cfg.policy_delay == 0:
            stats.update(self._update_actor(obs, batch, clone_only))
            soft_update(self.actor_target, self.actor, cfg.tau)
            if self.actor_avg is not None:
                soft_update(self.actor_avg, self.actor, cfg.actor_average)
            soft_update(self.critic_target, self.critic, cfg.tau)
        return stats

    def _update_actor(self, obs: torch.Tensor, batch: Batch, clone_only: bool = False) -> dict[str, float]:
        critic_params = list(self.critic.parameters())
        for p in critic_params:  # the actor's loss needs dQ/da, not the critic's weight gradients: skip them
            p.requires_grad_(False)
        try:
            return self._actor_step(obs, batch, clone_only)
        finally:
            for p in critic_params:
                p.requires_grad_(True)

    def _actor_step(self, obs: torch.Tensor, batch: Batch, clone_only: bool) -> dict[str, float]:
        cfg = self.config
        preact = cfg.actor_preact_weight > 0.0 and not clone_only
        if preact:
            pre = self.actor.preactivation(obs)
            action = torch.tanh(pre)
        else:
            action = self.actor(obs)
        q_pi = self.critic.first(obs, action)
        actor_loss = -q_pi.mean()
        bc_loss = torch.zeros(())
        share = 0.0
        n_labelled = float(batch.labelled.sum())
        cloning = (cfg.bc_weight > 0.0 or clone_only) and n_labelled > 0  # (on or off by the starting weight)
        if cloning and cfg.bc_normalise_q:
            actor_loss = actor_loss / q_pi.abs().mean().detach().clamp_min(1e-6)
        if cloning:
            mask = batch.labelled
            if cfg.q_filter and not clone_only:
                with torch.no_grad():
                    q_expert = self.critic.first(obs, batch.expert_action)
                    mask = mask * (q_expert > q_pi.detach()).float()
            err = ((action - batch.expert_action) ** 2).sum(-1)
            if cfg.bc_slow_weight != 1.0:  # a weighted mean: the slow actions weigh bc_slow_weight times
                slow = (batch.expert_action.norm(dim=-1) < cfg.bc_slow_below).float()
                weight = 1.0 + (cfg.bc_slow_weight - 1.0) * slow
                bc_loss = (err * mask * weight).sum() / (batch.labelled * weight).sum()
            else:
                bc_loss = (err * mask).sum() / n_labelled
            share = float(mask.sum()) / n_labelled
        loss = bc_loss if clone_only else actor_loss + self.bc_weight * bc_loss
        if preact:  # keeps tanh out of saturation, where dQ/da * (1 - a^2) vanishes and the actor stops learning
            loss = loss + cfg.actor_preact_weight * pre.square().mean()
        self.actor_opt.zero_grad(set_to_none=True)
        loss.backward()
        if cfg.grad_clip > 0:
            nn.utils.clip_grad_norm_(self.actor.parameters(), cfg.grad_clip)
        self.actor_opt.step()
        return {"actor_loss": actor_loss.item(), "bc_loss": bc_loss.item(), "bc_share": share}

    def polish(self, obs: np.ndarray, target: np.ndarray, epochs: int, generator: torch.Generator) -> list[float]:
        """Fit a freshly initialised actor (of ``config.polish_hidden`` widths, or ``hidden`` if that is empty;
        ``set_actor_widths``) to ``target`` actions (n, act_dim) for raw observations ``obs``
        (n, obs_dim) by the cloning loss alone (``config.polish_epochs``): ``epochs`` shuffled passes in
        minibatches of ``batch_size``, Adam from ``polish_lr`` annealed to 0 by a cosine. The initial weights come
        from ``generator``; the normaliser stays as it is. Returns the mean squared error (summed over action
        components) of each epoch."""
        cfg = self.config
        widths = tuple(cfg.polish_hidden) or tuple(cfg.hidden)
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(int(torch.randint(2**31 - 1, (1,), generator=generator)))
            fresh = self._new_actor(widths)
        if widths != tuple(cfg.hidden):
            self.set_actor_widths(widths)
        self.actor.load_state_dict(fresh.state_dict())
        x = self.norm(torch.as_tensor(obs, dtype=torch.float32))
        y = torch.as_tensor(target, dtype=torch.float32)
        n = len(x)
        per_epoch = max(n // cfg.batch_size, 1)
        opt = torch.optim.Adam(self.actor.parameters(), lr=cfg.polish_lr)
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=epochs * per_epoch)
        losses = []
        for _ in range(epochs):
            order = torch.randperm(n, generator=generator)
            total = 0.0
            for i in range(per_epoch):
                idx = order[i * cfg.batch_size : (i + 1) * cfg.batch_size]
                with self.precision():
                    loss = ((self.actor(x[idx]) - y[idx]) ** 2).sum(-1).mean()
                opt.zero_grad(set_to_none=True)
                loss.backward()
                if cfg.grad_clip > 0:
                    nn.utils.clip_grad_norm_(self.actor.parameters(), cfg.grad_clip)
                opt.step()
                sched.step()
                total += loss.item()
            losses.append(total / per_epoch)
        self.actor_target.load_state_dict(self.actor.state_dict())
        return losses

    def set_actor_widths(self, widths: tuple[int, ...]) -> None:
        """Replace the actor, its target and its optimiser by ones with hidden ``widths`` (freshly initialised):
        the online actor (``config.hidden``) or the final fit's own (``config.polish_hidden``); the critic is left
        as it is."""
        cfg = self.config
        if self.actor_avg is not None:
            raise ValueError("the averaged actor (actor_average) cannot follow a replaced actor")
        self.actor = self._new_actor(tuple(widths))
        self.actor_target = copy.deepcopy(self.actor)
        for p in self.actor_target.parameters():
            p.requires_grad_(False)
        self.actor_opt = torch.optim.Adam(self.actor.parameters(), lr=cfg.actor_lr, fused=True)

    def _new_actor(self, widths: tuple[int, ...]) -> nn.Module:
        """A freshly initialised actor of ``config.actor_arch`` with hidden (head) ``widths``."""
        if self.sets:
            return SetActor(self.shapes, self.sets, self.act_dim, widths, tuple(self.config.set_hidden))
        return Actor(self.obs_dim, self.act_dim, widths)

    # -- state ----------------------------------------------------------------------------------------------
    def state_dict(self) -> dict[str, object]:
        """Every network, optimiser and counter (tensors and ints only)."""
        return {
            "norm": self.norm.state_dict(),
            "actor": self.actor.state_dict(),
            "critic": self.critic.state_dict(),
            "actor_target": self.actor_target.state_dict(),
            "critic_target": self.critic_target.state_dict(),
            "actor_opt": self.actor_opt.state_dict(),
            "critic_opt": self.critic_opt.state_dict(),
            "generator": self.generator.get_state(),
            "updates": self.updates,
            **({"actor_avg": self.actor_avg.state_dict()} if self.actor_avg is not None else {}),
        }

    def load_state_dict(self, state: dict[str, object]) -> None:
        """Restore what ``state_dict`` returned; a network of another shape raises ``ValueError``."""
        try:
            for name in ("norm", "actor", "critic", "actor_target", "critic_target"):
                getattr(self, name).load_state_dict(state[name])
            if self.actor_avg is not None:
                self.actor_avg.load_state_dict(state["actor_avg"])
            self.actor_opt.load_state_dict(state["actor_opt"])
            self.critic_opt.load_state_dict(state["critic_opt"])
        except (RuntimeError, KeyError) as err:
            raise ValueError(f"the checkpoint's networks do not match this configuration: {err}") from err
        self.generator.set_state(state["generator"])
        self.updates = int(state["updates"])

    def export_actor(self, averaged: bool = False) -> dict[str, np.ndarray]:
        """The greedy policy as plain arrays (float32): the normaliser's statistics as ``forward`` applies them,
        each head layer's weight and bias (``w<i>``, ``b<i>``) and a set actor's encoder layers
        (``<set>.w<i>``, ``<set>.b<i>``); ``actor_meta`` gives the record that goes with them. ``averaged``: the
        slow average of the actor (``config.actor_average``) in place of the actor."""
        if averaged and self.actor_avg is None:
            raise ValueError("no averaged actor: the run's config has actor_average = 0")
        actor = self.actor_avg if averaged else self.actor
        mean, std = self.norm.stats()
        out: dict[str, np.ndarray] = {
            "norm_enabled": np.array(self.norm.enabled),
            "norm_mean": mean.numpy().astype(np.float32),
            "norm_std": std.numpy().astype(np.float32),
            "norm_clip": np.array(self.norm.clip, dtype=np.float32),
        }
        if self.sets:
            nets = {"": actor.head, **{f"{name}.": actor.encoders[name] for name in self.sets}}
        else:
            nets = {"": actor.net}
        for prefix, net in nets.items():
            linear = [m for m in net if isinstance(m, nn.Linear)]
            for i, layer in enumerate(linear):
                out[f"{prefix}w{i}"] = layer.weight.detach().numpy().astype(np.float32)
                out[f"{prefix}b{i}"] = layer.bias.detach().numpy().astype(np.float32)
        return out

    def export_critic(self) -> tuple[dict[str, np.ndarray], dict[str, Any]] | None:
        """The critic as plain arrays (float32) for an actor file (``deck_sim.policies.actors.CRITIC_PREFIX``:
        each head's layers ``critic.q<h>.w<i>``, ``critic.q<h>.b<i>``) and the record that goes with them (heads and
        ``twin_min_weight``), so that the file's policy can rate actions as the run rated them. None for a critic
        with ``LayerNorm`` (``critic_layer_norm``), which the numpy policy does not run."""
        if self.config.critic_layer_norm:
            return None
        out: dict[str, np.ndarray] = {}
        for h, head in enumerate(self.critic.heads):
            for i, layer in enumerate(m for m in head if isinstance(m, nn.Linear)):
                out[f"{CRITIC_PREFIX}q{h}.w{i}"] = layer.weight.detach().numpy().astype(np.float32)
                out[f"{CRITIC_PREFIX}q{h}.b{i}"] = layer.bias.detach().numpy().astype(np.float32)
        return out, {"heads": len(self.critic.heads), "twin_min_weight": float(self.config.twin_min_weight)}

    def actor_meta(self) -> dict[str, Any]:
        """The format fields of the exported actor's record: ``deck_sim.actor/1`` for an MLP actor,
        ``deck_sim.actor/3`` with its ``sets`` for a set actor."""
        if self.sets:
            return {"format": ACTOR_FORMAT_SETS, "sets": {k: list(v) for k, v in self.sets.items()}}
        return {"format": ACTOR_FORMAT}

"""A training run's ``checkpoint.pt``: what it holds, how it is written, read and checked, and how a trainer is put
back exactly where it stood.

A checkpoint is taken between steps and written atomically (a crash while writing leaves the previous one). It
holds the networks, optimisers, replay buffer, noise, the random generators' states, the run's counters and, per
environment, its episode's index (hence its reset seed) and the actions taken in that episode. Resuming rebuilds
each environment, resets it with its episode's seed and replays those actions (the physics is deterministic for a
seed), checks that it arrives at the checkpointed observation, and goes on; the CSV logs are cut back to the
checkpoint's step.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from training.config import ConfigError, TrainConfig, bc_weight_at, train_episode_seed

if TYPE_CHECKING:
    from training.loop import Trainer

log = logging.getLogger(__name__)

CHECKPOINT_FORMAT = "deck_sim.checkpoint/1"

RESUMABLE_CHANGES = ("total_steps", "polish_epochs", "polish_lr", "polish_hidden", "dagger_steps")
"""Config fields a resumed run may change: a longer run, or a final cloning fit or a DAgger round added to a
finished one."""


class CheckpointError(RuntimeError):
    """A checkpoint that cannot be read, or that belongs to another configuration."""


def _atomic_torch_save(obj: Any, path: Path) -> None:
    tmp = path.with_name(path.name + ".tmp")
    torch.save(obj, tmp)
    os.replace(tmp, path)


def load_checkpoint(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read a checkpoint written by ``Trainer``; ``CheckpointError`` naming the file if it cannot be read."""
    path = Path(path)
    if not path.exists():
        raise CheckpointError(f"{path}: no checkpoint to resume from")
    try:
        state = torch.load(path, weights_only=True)
    except Exception as err:  # torch raises many types for a damaged file (pickle, zip, runtime errors)
        raise CheckpointError(f"{path}: not a readable checkpoint (corrupt or truncated?): {err}") from err
    if not isinstance(state, dict) or state.get("format") != CHECKPOINT_FORMAT:
        raise CheckpointError(f"{path}: not a deck_sim training checkpoint (format {CHECKPOINT_FORMAT!r})")
    return state


def config_from_checkpoint(run_dir: str | os.PathLike[str]) -> TrainConfig:
    """The configuration stored in ``run_dir/checkpoint.pt`` (for ``--resume`` without repeating the options)."""
    state = load_checkpoint(Path(run_dir) / "checkpoint.pt")
    try:
        return TrainConfig.from_dict(state["config"])
    except ConfigError as err:
        raise CheckpointError(f"{run_dir}/checkpoint.pt: its config is not valid here: {err}") from err


def comparable(saved: dict[str, Any]) -> dict[str, Any]:
    """A checkpoint's config in ``to_dict`` form (fields it lacks take their defaults, as a resumed config does),
    or as saved where it does not parse (its difference is then named as it stands)."""
    try:
        return TrainConfig.from_dict(saved).to_dict()
    except (ConfigError, TypeError, ValueError):
        return saved


def check_compatible(config: TrainConfig, saved: dict[str, Any], path: Path) -> None:
    """``CheckpointError`` unless the checkpoint ``path``'s config ``saved`` equals ``config`` but for
    ``RESUMABLE_CHANGES``; the message names up to five differing fields."""
    mine = config.to_dict()
    saved = comparable(saved)
    diff = [k for k in sorted(set(mine) | set(saved)) if k not in RESUMABLE_CHANGES and mine.get(k) != saved.get(k)]
    if diff:
        detail = "; ".join(f"{k}: checkpoint {saved.get(k)!r}, now {mine.get(k)!r}" for k in diff[:5])
        raise CheckpointError(f"{path} was written by another configuration ({detail})")


def check_polished(trainer: Trainer, saved: dict[str, Any], end: int) -> None:
    """A polished run is finished: its actor is no longer the online one, so it can be neither extended to ``end``
    steps nor polished again with other settings, nor can its DAgger round be undone."""
    if end > trainer.step:
        raise CheckpointError(
            f"{trainer.run_dir} was polished at step {trainer.step} (polish_epochs): it cannot be extended to {end} "
            "steps; train a new run with more steps instead"
        )
    if trainer.dagger_done > trainer.config.dagger_steps:
        raise CheckpointError(
            f"{trainer.run_dir} had a DAgger round of {trainer.dagger_done} steps (dagger_steps); it cannot be "
            f"undone to {trainer.config.dagger_steps}"
        )
    mine, saved, default = trainer.config.to_dict(), comparable(saved), TrainConfig().to_dict()
    for k in ("polish_epochs", "polish_lr", "polish_hidden"):
        value = saved.get(k, default[k])
        if value != mine[k]:
            raise CheckpointError(
                f"{trainer.run_dir} was polished with {k} = {value!r}; it cannot be polished again with {mine[k]!r}"
            )


def save_checkpoint(trainer: Trainer) -> Path:
    """Write ``trainer``'s ``checkpoint.pt`` atomically; its path."""
    stats = trainer.stats
    state = {
        "format": CHECKPOINT_FORMAT,
        "config": trainer.config.to_dict(),
        "step": trainer.step,
        "wall": trainer.wall,
        "update_debt": trainer.update_debt,
        "episodes_done": stats.episodes,
        "recent": [[o, float(r)] for o, r in stats.recent],
        "last_stats": dict(stats.updates),
        "best_success": trainer.best_success,
        "polished": trainer.polished,
        "dagger_done": trainer.dagger_done,
        "demo_summary": dict(trainer.demo_summary),
        "agent": trainer.agent.state_dict(),
        "buffer": trainer.buffer.state_dict(),
        "noise": trainer.noise.state_dict(),
        "rng": trainer.rng.bit_generator.state,
        "torch_rng": torch.get_rng_state(),
        "slots": [
            {
                "episode": s.episode,
                "stage": s.stage,
                "ret": s.ret,
                "length": s.length,
                "actions": torch.from_numpy(np.asarray(s.actions, dtype=np.float64).reshape(-1, 2)),
                "obs": torch.from_numpy(np.asarray(s.obs, dtype=np.float32)),
            }
            for s in trainer.slots
        ],
    }
    path = trainer.run_dir / "checkpoint.pt"
    _atomic_torch_save(state, path)
    return path


def restore(trainer: Trainer, state: dict[str, Any]) -> None:
    """Put ``trainer`` (freshly built from the checkpoint's config) back where ``state`` stood: networks, replay,
    noise, counters and random generators, every environment replayed to its checkpointed observation, and the
    CSV logs cut back to the checkpoint's step."""
    path = trainer.run_dir / "checkpoint.pt"
    try:
        # a polished checkpoint holds the fit's actor, of the widths its own config gave the fit
        widths = tuple(comparable(state["config"]).get("polish_hidden") or ())
        if state.get("polished", False) and widths:
            trainer.agent.set_actor_widths(widths)
        trainer.agent.load_state_dict(state["agent"])
        trainer.buffer.load_state_dict(state["buffer"])
        trainer.noise.load_state_dict(state["noise"])
    except (ValueError, KeyError) as err:
        raise CheckpointError(f"{path}: {err}") from err
    trainer.step = int(state["step"])
    trainer.agent.bc_weight = bc_weight_at(trainer.config, trainer.step)
    trainer.wall = float(state["wall"])
    trainer.update_debt = float(state["update_debt"])
    trainer.stats.episodes = int(state["episodes_done"])
    trainer.stats.recent.extend((o, float(r)) for o, r in state["recent"])
    trainer.stats.updates = dict(state["last_stats"])
    trainer.best_success = float(state["best_success"])
    trainer.polished = bool(state.get("polished", False))  # absent from a checkpoint without the final fit
    trainer.dagger_done = int(state.get("dagger_done", 0))
    trainer.demo_summary = dict(state["demo_summary"])
    trainer.rng.bit_generator.state = state["rng"]
    for slot, saved in zip(trainer.slots, state["slots"], strict=True):
        slot.episode = int(saved["episode"])
        trainer.start_episode(slot, stage=int(saved["stage"]))
        actions = saved["actions"].numpy()
        if len(actions):  # replay the episode so far: same seed, same actions, same state (planner included)
            seed = train_episode_seed(trainer.config.seed, slot.index, slot.episode)
            slot.obs = trainer.agent_obs(slot, trainer.envs.replay(slot.index, seed, actions))
            slot.actions = list(actions)
        if not np.array_equal(slot.obs, saved["obs"].numpy()):
            raise CheckpointError(
                f"environment {slot.index} did not replay to its checkpointed state: the scene or deck_sim "
                "changed since the checkpoint was written"
            )
        slot.ret, slot.length = float(saved["ret"]), int(saved["length"])
    trainer.noise.load_state_dict(state["noise"])  # start_episode reset it
    torch.set_rng_state(state["torch_rng"])
    if trainer.runlog.open_csv(truncate_after=trainer.step):
        trainer.last_eval_step = trainer.step  # the run's evaluation at this step is on file already
    log.info("resumed %s at step %d", trainer.run_dir, trainer.step)

"""A training run's ``checkpoint.pt``: what it holds, how it is written, read and checked, and how a trainer is put
back exactly where it stood.

A checkpoint is taken between steps. It holds the networks, optimisers, replay buffer, noise, the random
generators' states, the run's counters and, per environment, its episode's index (hence its reset seed) and the
actions taken in that episode. Resuming rebuilds each environment, resets it with its episode's seed and replays
those actions (the physics is deterministic for a seed), checks that it arrives at the checkpointed observation,
and goes on; the CSV logs are cut back to the checkpoint's step.

The file is ``torch.save``'s zip archive with the SHA-256 of that archive in the zip's comment (``CHECKSUM_TAG``
and 64 hex digits): ``torch.load`` reads it as it is, and ``load_checkpoint`` refuses a file whose digest does not
match, or that ends in neither such a comment nor a plain zip record, with a ``CheckpointError`` naming it, before
torch reads a byte. A plain ``torch.save`` archive without the comment is read unverified, with a one-line warning,
so that run folders holding such checkpoints still resume; the run's next checkpoint carries the digest.

Each write goes to a temporary file, synced, then moves the current ``checkpoint.pt`` to ``checkpoint.prev.pt`` and
itself into place: a crash while writing leaves the last complete checkpoint, as ``checkpoint.pt`` or, between the
two moves, as ``checkpoint.prev.pt`` alone (which ``--resume`` then names).

A damaged ``checkpoint.pt`` is not replaced by the previous one on its own: ``--resume`` refuses it, and the message
gives the previous one's step and the ``mv`` command that makes it the checkpoint to resume from. Resuming from it
is exact as well (the run goes on as an unbroken run from that step, its logs cut back to it), but what the run did
after that step is dropped, so the choice is the user's.
"""

from __future__ import annotations

import hashlib
import logging
import os
import shlex
from pathlib import Path
from typing import TYPE_CHECKING, Any

import torch

from training.config import ConfigError, TrainConfig, bc_weight_at

if TYPE_CHECKING:
    from deck_sim.policies import LearnedPolicy
    from training.ddpg import DDPGAgent
    from training.loop import Trainer

log = logging.getLogger(__name__)

CHECKPOINT_FORMAT = "deck_sim.checkpoint/1"

CHECKPOINT = "checkpoint.pt"
"""A run folder's latest checkpoint."""
PREVIOUS = "checkpoint.prev.pt"
"""The checkpoint written before ``CHECKPOINT``, kept by each write."""
CHECKSUM_TAG = b"deck_sim.checkpoint sha256 "
"""The start of a checkpoint's zip comment; the SHA-256 of the archive without it follows, in hex."""

_EOCD = b"PK\x05\x06"  # signature of the zip's end-of-central-directory record (22 bytes and the comment, last)
_EOCD_SIZE = 22
_COMMENT_SIZE = len(CHECKSUM_TAG) + 64
_warned: set[tuple[str, int, int]] = set()  # the checkpoints without a checksum this process has warned of

RESUMABLE_CHANGES = ("total_steps", "polish_epochs", "polish_lr", "polish_hidden", "dagger_steps")
"""Config fields a resumed run may change: a longer run (not with a curriculum, whose stages end at fractions of
``total_steps``), or a final cloning fit or a DAgger round added to a finished one."""


class CheckpointError(RuntimeError):
    """A checkpoint that cannot be read, or that belongs to another configuration."""


def _sha256(f: Any, size: int) -> Any:
    """The SHA-256 of the first ``size`` bytes of the open file ``f``."""
    digest = hashlib.sha256()
    f.seek(0)
    while size > 0:
        chunk = f.read(min(size, 1 << 22))
        if not chunk:
            break
        digest.update(chunk)
        size -= len(chunk)
    return digest


def _write(state: dict[str, Any], path: Path) -> None:
    """``torch.save`` ``state`` with its digest in the zip comment, atomically; the file it replaces becomes
    ``PREVIOUS``."""
    tmp = path.with_name(path.name + ".tmp")
    torch.save(state, tmp)
    with open(tmp, "r+b") as f:
        size = f.seek(0, os.SEEK_END)
        f.seek(size - _EOCD_SIZE)
        if f.read(_EOCD_SIZE)[:4] != _EOCD:  # torch writes no zip comment: its archive ends with the bare record
            raise RuntimeError(f"{tmp}: torch.save wrote no plain zip end record; cannot add the checksum")
        comment = CHECKSUM_TAG + _sha256(f, size).hexdigest().encode()
        f.seek(size - 2)  # the record's comment length, 0 as torch wrote it
        f.write(len(comment).to_bytes(2, "little") + comment)
        f.flush()
        os.fsync(f.fileno())
    if path.exists():
        # the file it replaces is linked, not moved, to PREVIOUS: a stop between the two renames still leaves a
        # checkpoint under ``path``
        linked = path.with_name(PREVIOUS + ".tmp")
        linked.unlink(missing_ok=True)
        try:
            os.link(path, linked)
            os.replace(linked, path.with_name(PREVIOUS))
        except OSError:  # (a filesystem without hard links)
            os.replace(path, path.with_name(PREVIOUS))
    os.replace(tmp, path)


def _verify(path: Path) -> bool:
    """Check ``path``'s digest: True if it matches, False for a checkpoint without one (a plain zip end record);
    ``CheckpointError`` for a mismatch or a file that ends in neither."""
    with open(path, "rb") as f:
        size = f.seek(0, os.SEEK_END)
        tail_size = min(size, _EOCD_SIZE + _COMMENT_SIZE)
        f.seek(size - tail_size)
        tail = f.read(tail_size)
        if len(tail) >= _EOCD_SIZE and tail[-_EOCD_SIZE:][:4] == _EOCD and tail[-2:] == b"\0\0":
            return False
        comment, record = tail[-_COMMENT_SIZE:], tail[:_EOCD_SIZE]
        signed = (
            len(tail) == _EOCD_SIZE + _COMMENT_SIZE
            and record[:4] == _EOCD
            and int.from_bytes(record[-2:], "little") == _COMMENT_SIZE
            and comment.startswith(CHECKSUM_TAG)
        )
        if not signed:
            what = "no checkpoint record at its end: another kind of file, or a damaged or cut-short one"
            what = "an empty file" if size == 0 else what
            raise CheckpointError(f"{path}: not a readable checkpoint: not a deck_sim training checkpoint ({what})")
        digest = _sha256(f, size - _COMMENT_SIZE - 2)
        digest.update(b"\0\0")  # the comment length as torch wrote it
    if digest.hexdigest().encode() != comment[len(CHECKSUM_TAG) :]:
        raise CheckpointError(
            f"{path}: not a readable checkpoint: its content does not match its SHA-256 checksum (the file is damaged)"
        )
    return True


def load_checkpoint(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read a checkpoint written by ``Trainer``, its checksum checked first; ``CheckpointError`` naming the file,
    in one line, if it is missing, damaged or not a checkpoint. A checkpoint without a checksum is read with a
    warning."""
    path = Path(path)
    if not path.exists():
        raise CheckpointError(f"{path}: no checkpoint to resume from")
    try:
        verified = _verify(path)
    except OSError as err:
        raise CheckpointError(f"{path}: not a readable checkpoint: {err.strerror or err}") from err
    try:
        state = torch.load(path, weights_only=True)
    except Exception as err:  # torch raises many types for a damaged file (pickle, zip, runtime errors)
        first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise CheckpointError(
            f"{path}: not a readable checkpoint: torch cannot load it ({first})"
            + ("" if verified else "; it carries no checksum: not a deck_sim training checkpoint, or a damaged one")
        ) from err
    if not isinstance(state, dict) or state.get("format") != CHECKPOINT_FORMAT:
        raise CheckpointError(f"{path}: not a deck_sim training checkpoint (format {CHECKPOINT_FORMAT!r})")
    if not verified:
        stat = path.stat()
        key = (str(path.resolve()), stat.st_size, stat.st_mtime_ns)
        if key not in _warned:  # once per file: ``--resume`` reads the checkpoint for its plan and for the trainer
            _warned.add(key)
            log.warning("%s: a checkpoint without a checksum, read unverified (the run's next one has it)", path)
    return state


def load_run_agent(run_dir: str | os.PathLike[str]) -> tuple[dict[str, Any], TrainConfig, DDPGAgent]:
    """A DDPG or MDDPG run folder's checkpoint (``load_run_checkpoint``), its config and its agent as last saved
    (networks, normaliser, optimisers; a fitted checkpoint's actor at the fit's widths), for tools that read a run
    without resuming it. ``CheckpointError`` naming the folder when it holds no checkpoint."""
    from training.ddpg import DDPGAgent  # (the trainer's modules import this one)
    from training.envs import scene_layout

    run_dir = Path(run_dir)
    if not (run_dir / CHECKPOINT).is_file() and not (run_dir / PREVIOUS).is_file():
        raise CheckpointError(f"{run_dir}: no {CHECKPOINT} (the folder of a DDPG or MDDPG training run holds one)")
    state = load_run_checkpoint(run_dir)
    cfg = checkpoint_config(state, run_dir / CHECKPOINT)
    buf = state["buffer"]
    shapes = None
    if cfg.actor_arch == "sets":  # the set actor reads the observation's layout
        shapes = scene_layout(cfg.scene, cfg.predictor, cfg.scene_overrides).shapes
    agent = DDPGAgent(buf["obs"].shape[1], buf["action"].shape[1], cfg, shapes=shapes)
    widths = tuple(comparable(state["config"]).get("polish_hidden") or ())
    if state.get("polished", False) and widths:
        agent.set_actor_widths(widths)
    agent.load_state_dict(state["agent"])
    return state, cfg, agent


def checkpoint_policy(run_dir: str | os.PathLike[str], averaged: bool = False) -> LearnedPolicy:
    """The actor of a DDPG or MDDPG run folder's checkpoint (``load_run_agent``; ``averaged``: the slow average of
    its actor, a run with ``actor_average``) as a policy that carries the critic of the same moment
    (``training.final_fit.save_actor``'s file, not written): its ``meta`` is the run's actor record at the
    checkpoint's step. ``CheckpointError`` naming the folder when it holds no checkpoint; ``ValueError`` when the
    critic has ``LayerNorm``, which the numpy policy does not run, or an averaged actor is asked of a run without
    one."""
    from deck_sim.policies import LearnedPolicy, load_actor
    from training.envs import scene_layout
    from training.final_fit import actor_meta

    run_dir = Path(run_dir)
    state, cfg, agent = load_run_agent(run_dir)
    if averaged and agent.actor_avg is None:
        raise ValueError(f"{run_dir}: the run keeps no averaged actor (actor_average is {cfg.actor_average})")
    critic = agent.export_critic()
    if critic is None:
        raise ValueError(f"{run_dir}: the run's critic has LayerNorm (critic_layer_norm), which the numpy policy "
                         "does not run")
    template = next((p for p in (run_dir / "actor.npz", run_dir / "actor_best.npz") if p.is_file()), None)
    commit = str(load_actor(template).meta.get("git_commit", "unknown")) if template else "unknown"
    layout = scene_layout(cfg.scene, cfg.predictor, cfg.scene_overrides)
    meta = {**actor_meta(cfg, layout, agent, int(state["step"]), commit, bool(state.get("polished", False))),
            "critic": critic[1], **({"averaged": cfg.actor_average} if averaged else {})}
    return LearnedPolicy({**agent.export_actor(averaged), **critic[0]}, meta,
                         source=f"{run_dir} (checkpoint{', averaged actor' if averaged else ''})")


def load_run_checkpoint(run_dir: str | os.PathLike[str]) -> dict[str, Any]:
    """Read ``run_dir``'s ``checkpoint.pt`` (``load_checkpoint``). If it is missing or damaged and
    ``checkpoint.prev.pt`` reads, the ``CheckpointError`` gives that one's step and the command that makes it the
    checkpoint to resume from; the previous one is never taken in its place silently."""
    run_dir = Path(run_dir)
    path, previous = run_dir / CHECKPOINT, run_dir / PREVIOUS
    try:
        return load_checkpoint(path)
    except CheckpointError as err:
        if not previous.exists():
            raise
        try:
            step = int(load_checkpoint(previous)["step"])
        except (CheckpointError, KeyError, TypeError, ValueError):
            raise CheckpointError(f"{err}; the previous checkpoint {previous} cannot be read either") from err
        raise CheckpointError(
            f"{err}; the previous checkpoint (step {step}) is intact: to resume from it, "
            f"mv {shlex.quote(str(previous))} {shlex.quote(str(path))}"
        ) from err


def checkpoint_config(state: dict[str, Any], path: str | os.PathLike[str]) -> TrainConfig:
    """The ``TrainConfig`` a checkpoint ``state`` read from ``path`` was written with."""
    try:
        return TrainConfig.from_dict(state["config"])
    except ConfigError as err:
        raise CheckpointError(f"{path}: its config is not valid here: {err}") from err


def steps_done(state: dict[str, Any]) -> int:
    """The online environment steps a checkpoint's run has done (a DAgger round's steps left out)."""
    return int(state["step"]) - int(state.get("dagger_done", 0))


def check_budget(total_steps: int, state: dict[str, Any], path: str | os.PathLike[str]) -> None:
    """``CheckpointError`` naming both if ``total_steps`` is below the steps the checkpoint's run has done."""
    done = steps_done(state)
    if total_steps < done:
        raise CheckpointError(
            f"{path}: the run has done {done} steps; a budget of {total_steps} steps (total_steps, --steps) is "
            "below that"
        )


def config_from_checkpoint(run_dir: str | os.PathLike[str]) -> TrainConfig:
    """The configuration stored in ``run_dir/checkpoint.pt`` (for ``--resume`` without repeating the options)."""
    return checkpoint_config(load_run_checkpoint(run_dir), Path(run_dir) / CHECKPOINT)


def comparable(saved: dict[str, Any]) -> dict[str, Any]:
    """A checkpoint's config in ``to_dict`` form (fields it lacks take their defaults, as a resumed config does),
    or as saved where it does not parse (its difference is then named as it stands)."""
    try:
        return TrainConfig.from_dict(saved).to_dict()
    except (ConfigError, TypeError, ValueError):
        return saved


def check_compatible(config: TrainConfig, saved: dict[str, Any], path: Path) -> None:
    """``CheckpointError`` unless the checkpoint ``path``'s config ``saved`` equals ``config`` but for
    ``RESUMABLE_CHANGES`` (with a curriculum, ``total_steps`` too); the message names up to five differing
    fields."""
    mine = config.to_dict()
    saved = comparable(saved)
    diff = [k for k in sorted(set(mine) | set(saved)) if k not in RESUMABLE_CHANGES and mine.get(k) != saved.get(k)]
    if mine.get("curriculum") and mine.get("total_steps") != saved.get("total_steps"):
        diff.insert(0, "total_steps")  # (the stages end at fractions of it: another length would move them)
    if diff:
        detail = "; ".join(f"{k}: checkpoint {saved.get(k)!r}, now {mine.get(k)!r}" for k in diff[:5])
        raise CheckpointError(f"{path} was written by another configuration ({detail})")


def acting_workers(
    config: TrainConfig, backend: str, workers: int | None, state: dict[str, Any] | None, path: str | os.PathLike[str]
) -> int:
    """The workers a run steps its environments in (``Trainer``'s ``workers``; 0: inline), checked: ``ConfigError``
    for a count the backend cannot take, ``CheckpointError`` where a resumed run (checkpoint ``state`` read from
    ``path``) would act in another count of groups than it did (a checkpoint without the count acted in one)."""
    saved = None if state is None else int(state.get("groups", 1))
    if workers is None:
        workers = (1 if config.env_worker else 0) if backend == "local" else 1
        workers = saved if saved is not None and saved > 1 else workers
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < (0 if backend == "local" else 1):
        least = "0 (inline) or more" if backend == "local" else "at least 1"
        raise ConfigError(f"workers: {least} on the {backend} backend, got {workers!r}")
    if workers > config.num_envs:
        raise ConfigError(f"workers: at most num_envs ({config.num_envs}), one environment each, got {workers}")
    if saved is not None and max(workers, 1) != saved:
        raise CheckpointError(
            f"{path}: the run acted in {saved} group(s) of environments; resume it with --workers {saved} "
            "(a run's numbers depend on that count)"
        )
    return workers


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
    """Write ``trainer``'s ``checkpoint.pt`` atomically with its checksum, the one it replaces kept as
    ``checkpoint.prev.pt``; its path."""
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
        "groups": max(trainer.workers, 1),
        "agent": trainer.agent.state_dict(),
        "buffer": trainer.buffer.state_dict(),
        "noise": trainer.noise.state_dict(),
        "hold": trainer.hold.state_dict(),
        "rng": trainer.rng.bit_generator.state,
        "torch_rng": torch.get_rng_state(),
        "slots": trainer.slot_states(),
    }
    path = trainer.run_dir / CHECKPOINT
    _write(state, path)
    return path


def restore(trainer: Trainer, state: dict[str, Any]) -> None:
    """Put ``trainer`` (freshly built from the checkpoint's config) back where ``state`` stood: networks, replay,
    noise, counters and random generators, every environment replayed to its checkpointed observation, and the
    CSV logs cut back to the checkpoint's step."""
    path = trainer.run_dir / CHECKPOINT
    try:
        # a polished checkpoint holds the fit's actor, of the widths its own config gave the fit (as load_run_agent)
        widths = tuple(comparable(state["config"]).get("polish_hidden") or ())
        if state.get("polished", False) and widths:
            trainer.agent.set_actor_widths(widths)
        trainer.agent.load_state_dict(state["agent"])
        trainer.buffer.load_state_dict(state["buffer"])
        trainer.noise.load_state_dict(state["noise"])
        if "hold" in state:  # absent from a checkpoint written before held actions existed (none were held)
            trainer.hold.load_state_dict(state["hold"])
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
    trainer.restore_slots(state["slots"])
    trainer.noise.load_state_dict(state["noise"])  # start_episode reset it, and the hold with it
    if "hold" in state:
        trainer.hold.load_state_dict(state["hold"])
    torch.set_rng_state(state["torch_rng"])
    if trainer.runlog.open_csv(truncate_after=trainer.step):
        trainer.last_eval_step = trainer.step  # the run's evaluation at this step is on file already
    log.info("resumed %s at step %d", trainer.run_dir, trainer.step)

"""The end of a training run: the final cloning fit (``polish_epochs``), the DAgger round (``dagger_steps``) and
the exported actor files.

When the online steps are done, ``finish`` evaluates the last actor (unless that step was evaluated already), then
fits a fresh actor to the planner's labels on the whole replay buffer (``polish``), then lets that fitted actor
drive for ``dagger_steps`` more steps, labelled by the planner, and fits again (``dagger_round``), and finally writes
``actor.npz``. Each part runs once per run: a finished run resumed with the fit or the round added does only what
it lacks. ``actor_best.npz`` is written by the trainer's evaluations; ``shipped_actor`` picks the one of the two
files a finished run ships; ``played_actor`` the file through which a run acts in each of ``PLAYS``.
"""

from __future__ import annotations

import hashlib
import logging
import os
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

import deck_sim
from deck_sim.policies import LearnedPolicy, write_actor_file
from deck_sim.progress import progress as progress_report
from training.config import TrainConfig
from training.ddpg import DDPGAgent
from training.envs import ObservationLayout

if TYPE_CHECKING:
    from training.loop import Trainer

log = logging.getLogger(__name__)


def actor_meta(
    config: TrainConfig, layout: ObservationLayout, agent: DDPGAgent, step: int, commit: str, polished: bool = False
) -> dict[str, Any]:
    """The record of an exported actor; ``commit`` is the source the training process runs (read at its start:
    the tree may change while a long run goes on)."""
    return {
        **agent.actor_meta(),
        "scene": config.scene,
        "scene_overrides": config.scene_overrides,
        "algo": config.algo,
        "predictor": config.predictor,
        "observation_keys": list(layout.keys),
        "observation_shapes": {k: list(v) for k, v in layout.shapes.items()},
        "trained_steps": int(step),
        "polished": bool(polished),
        "regime": config.regime,
        "config": config.to_dict(),
        "deck_sim_version": deck_sim.__version__,
        "git_commit": commit,
    }


def save_actor(path: str | os.PathLike[str], agent: DDPGAgent, meta: dict[str, Any], averaged: bool = False) -> None:
    """Write the agent's greedy actor (``averaged``: its slow average, ``DDPGAgent.actor_avg``) as a weights-only
    ``.npz`` (atomically), with the critic of the same moment (``DDPGAgent.export_critic``), which a policy that
    selects its actions by the critic reads (``deck_sim.policies.selecting``; the actor alone acts otherwise)."""
    arrays = agent.export_actor(averaged)
    critic = agent.export_critic()
    if critic is not None:
        arrays.update(critic[0])
        meta = {**meta, "critic": critic[1]}
    write_actor_file(path, arrays, meta, compress=False)


def shipped_actor(run_dir: str | os.PathLike[str]) -> Path:
    """The actor file of a finished run that ``scripts/train_shipped.py`` ships.

    A run whose final ``actor.npz`` is the cloning fit's (its own record says ``polished``) ships that file; any
    other run (stable-baselines3's, or one without the fit) the actor of its best periodic evaluation,
    ``actor_best.npz``. Picking the best of several short evaluations picks noise as much as skill: the two are
    compared on held-out episodes in ``docs/training.md``, "The run folder".
    """
    run = Path(run_dir)
    final = run / "actor.npz"
    if final.exists() and LearnedPolicy.load(final).meta.get("polished", False):
        return final
    return run / "actor_best.npz"


PLAYS = ("shipped", "averaged-select")
"""How a finished DDPG or MDDPG run acts on held-out episodes (``played_actor``):

- ``shipped``: the actor ``scripts/train_shipped.py`` ships (``shipped_actor``);
- ``averaged-select``: the slow average of its actor (``actor_avg.npz``, a run with ``actor_average``) choosing
  each action by the run's own critic among the averaged actor's action and ``SELECT_CANDIDATES`` candidates around
  it (``deck_sim.policies.selecting``, spread ``SELECT_SPREAD``). Both the actor and the critic are the run's, so the
  agent still learnt from nothing but what its run learnt from."""
SELECT_CANDIDATES = 64
"""Candidate actions around the actor's that the critic chooses among in play ``averaged-select``."""
SELECT_SPREAD = 0.3
"""Their spread in action units (the action box is [-1, 1] per axis)."""
AVERAGED_SELECT_FILE = "actor_avg_select.npz"
"""The actor file of play ``averaged-select`` in a run folder, written from ``actor_avg.npz`` by ``played_actor``."""


def play_settings(play: str) -> dict[str, Any]:
    """What else than the run's files decides how it acts in ``play``: the selection's ``candidates``, ``spread``
    and offsets' ``seed`` for ``averaged-select`` (as ``deck_sim.policies.selecting`` records them in ``meta``);
    empty for ``shipped``."""
    return {"candidates": SELECT_CANDIDATES, "spread": SELECT_SPREAD, "seed": 0} if play == "averaged-select" else {}


def played_actor(run_dir: str | os.PathLike[str], play: str = "shipped") -> Path:
    """The actor file through which a finished run acts in ``play`` (one of ``PLAYS``). For ``averaged-select``
    the file is written from ``actor_avg.npz`` and rewritten whenever it was not made from that file's bytes with
    today's ``play_settings`` (its ``meta`` records both); it is missing, like ``actor_avg.npz``, until a run with
    ``actor_average`` finishes (a stale one is removed). An ``actor_avg.npz`` written without its critic (by a run
    older than the critic's export) takes the critic of the run's checkpoint, which a finished run saved at the
    same step with the same averaged actor (``training.checkpoints.checkpoint_policy``; checked).
    ``ValueError`` for an unknown play, or an averaged actor without a critic whose checkpoint does not give it."""
    run = Path(run_dir)
    if play == "shipped":
        return shipped_actor(run)
    if play != "averaged-select":
        raise ValueError(f"unknown play {play!r}; expected one of {', '.join(PLAYS)}")
    from deck_sim.policies import selecting

    source, dest = run / "actor_avg.npz", run / AVERAGED_SELECT_FILE
    if not source.exists():
        dest.unlink(missing_ok=True)  # (made from an averaged actor that is gone)
        return dest
    digest = hashlib.sha256(source.read_bytes()).hexdigest()
    settings = play_settings(play)
    if dest.exists():
        try:
            meta = LearnedPolicy.load(dest).meta
        except (OSError, ValueError):  # (a damaged derived file is made again)
            meta = {}
        if meta.get("averaged_sha256") == digest and meta.get("select") == settings:
            return dest
    averaged = LearnedPolicy.load(source)
    if not averaged.critic_heads:
        averaged = _with_checkpoint_critic(run, averaged)
    chosen = selecting(averaged, settings["candidates"], settings["spread"], settings["seed"])
    LearnedPolicy(chosen.arrays, {**chosen.meta, "averaged_sha256": digest}, source=str(dest)).save(dest)  # atomic
    return dest


def _with_checkpoint_critic(run: Path, averaged: LearnedPolicy) -> LearnedPolicy:
    """``averaged`` (a run's ``actor_avg.npz`` without its critic) with the critic of the run's checkpoint, which
    must hold the same averaged actor at the same step; ``ValueError`` naming the mismatch otherwise."""
    from training.checkpoints import CheckpointError, checkpoint_policy

    try:
        saved = checkpoint_policy(run, averaged=True)
    except (CheckpointError, OSError) as err:
        raise ValueError(f"{run}: actor_avg.npz carries no critic, and the run's checkpoint gives none ({err})"
                         ) from None
    step, at = int(averaged.meta.get("trained_steps", -1)), int(saved.meta["trained_steps"])
    same = step == at and all(k in saved.arrays and np.array_equal(saved.arrays[k], v)
                              for k, v in averaged.arrays.items())
    if not same:
        raise ValueError(f"{run}: actor_avg.npz (step {step:,}) carries no critic, and the checkpoint's averaged "
                         f"actor (step {at:,}) is not the same actor, so its critic is not this actor's")
    return LearnedPolicy({**averaged.arrays, **{k: v for k, v in saved.arrays.items() if k not in averaged.arrays}},
                         {**averaged.meta, "critic": saved.meta["critic"]}, source=str(run / "actor_avg.npz"))


def polish(trainer: Trainer) -> None:
    """The final cloning fit on every labelled transition of the buffer (``polish_epochs``); its loss per epoch
    goes to TensorBoard as ``polish/bc_loss``."""
    cfg, buffer = trainer.config, trainer.buffer
    rows = np.flatnonzero(buffer.labelled[: buffer.size] > 0)
    obs, target = buffer.obs[rows], buffer.expert_action[rows]
    log.info("polishing the actor: %d epochs over %d labelled transitions", cfg.polish_epochs, len(rows))
    t0 = time.perf_counter()
    losses = trainer.agent.polish(obs, target, cfg.polish_epochs, torch.Generator().manual_seed(cfg.seed + 2))
    trainer._tick()
    trainer.polished = True
    for epoch, loss in enumerate(losses):
        trainer.runlog.scalar("polish/bc_loss", loss, epoch)
    log.info("polished in %.0f s: cloning loss %.4f -> %.4f", time.perf_counter() - t0, losses[0], losses[-1])


def dagger_round(trainer: Trainer) -> dict[str, Any] | None:
    """Drive the fitted actor for the ``dagger_steps`` not yet done (greedy, no updates), every state labelled by
    the planner, then fit again, evaluate and checkpoint. Returns the evaluation, or None if stopped first."""
    cfg = trainer.config
    steps = cfg.dagger_steps - trainer.dagger_done
    log.info("DAgger round: the fitted actor drives %d steps, labelled by the planner", steps)
    end = trainer.step + steps
    bar = progress_report(total=steps, desc="DAgger round", unit="step", disable=not trainer.progress, leave=False)
    with trainer.stop_on_sigint(), bar:
        while trainer.step < end and not trainer._stop:
            trainer.collect(explore=False)
            trainer._tick()
            bar.update(trainer.collected)
    if trainer.step < end:
        log.warning("the DAgger round stopped before its fit: --resume starts it again from the fitted run")
        return None
    polish(trainer)
    trainer.dagger_done = cfg.dagger_steps
    summary = trainer.evaluate()
    trainer.save_checkpoint()
    return summary


def finish(trainer: Trainer, last_eval: dict[str, Any]) -> dict[str, Any]:
    """After the run's last online step: the final evaluation, the fit and the DAgger round the config asks for and
    has not had, then ``actor.npz``. Returns the last evaluation's summary (``last_eval`` if none was made).

    A stop (Ctrl-C) skips what is left; a run stopped while its fit or its round is owed writes no ``actor.npz``.
    """
    cfg = trainer.config
    if trainer.last_eval_step != trainer.step:
        last_eval = trainer.evaluate()
        trainer.save_checkpoint()  # (with the best success so far: a later polish is compared with it)
    owed = bool(cfg.polish_epochs) and not trainer.polished
    if owed and not trainer._stop:
        # the checkpoint is written after the polished evaluation: a run that dies before it polishes again
        polish(trainer)
        last_eval = trainer.evaluate()
        trainer.save_checkpoint()
        owed = False
    if not owed and trainer.dagger_done < cfg.dagger_steps and not trainer._stop:
        # no checkpoint inside the round: one stopped before its fit starts again from the fitted run
        round_eval = dagger_round(trainer)
        owed = round_eval is None
        last_eval = round_eval or last_eval
    if not owed:
        meta = actor_meta(cfg, trainer.layout, trainer.agent, trainer.step, trainer.commit, trainer.polished)
        if trainer.agent.actor_avg is not None:
            save_actor(trainer.run_dir / "actor_avg.npz", trainer.agent, {**meta, "averaged": cfg.actor_average},
                       averaged=True)
        save_actor(trainer.run_dir / "actor.npz", trainer.agent, meta)
    return last_eval

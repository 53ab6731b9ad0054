"""One readable training loop for DDPG / MDDPG: collect, update, evaluate, checkpoint, log.

A run lives in one folder:
    config.json        the ``TrainConfig`` (every hyperparameter)
    progress.csv       training statistics every ``log_every`` steps (episode reward, success, collision and
                       timeout rates over the last 50 episodes, critic loss, Q, actor loss, steps per second)
    eval.csv           held-out evaluations (success, collision, timeout, reward, path ratio, turning angle)
    tb/                the same curves for TensorBoard
    checkpoint.pt      everything needed to continue exactly (networks, optimisers, replay, noise, RNG states,
                       each environment's episode seed and the actions taken in it); written atomically
    actor.npz          the final greedy actor, weights only (``deck_sim.policies.LearnedPolicy``)
    actor_best.npz     the actor of the best evaluation so far

Exact resume: a checkpoint is taken between steps. Resuming rebuilds each environment, resets it with its
episode's seed and replays the actions already taken in that episode (the physics is deterministic for a seed),
checks that it arrives at the checkpointed observation, and goes on; the CSV logs are cut back to the checkpoint.
"""

from __future__ import annotations

import contextlib
import csv
import json
import logging
import os
import signal
import time
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

import deck_sim
from deck_sim.metrics import outcome_of, summarize
from deck_sim.policies import LearnedPolicy
from deck_sim.rollout import git_commit, run_episode
from training.buffers import ReplayBuffer
from training.config import ConfigError, CurriculumStage, TrainConfig, bc_weight_at, train_episode_seed
from training.ddpg import DDPGAgent
from training.envs import (
    ObservationLayout,
    collect_demonstrations,
    env_layout,
    make_env,
    mover_pad_fills,
    stage_overrides,
)
from training.noise import make_noise
from training.runners import make_runner

log = logging.getLogger(__name__)

CHECKPOINT_FORMAT = "deck_sim.checkpoint/1"
PROGRESS_FIELDS = (
    "step",
    "episodes",
    "wall_s",
    "sps",
    "ep_reward",
    "success",
    "collision",
    "timeout",
    "critic_loss",
    "q",
    "actor_loss",
    "bc_loss",
    "noise_sigma",
    "stage",
    "updates",
)
EVAL_FIELDS = (
    "step",
    "wall_s",
    "episodes",
    "success",
    "collision",
    "timeout",
    "reward",
    "path_ratio",
    "turning_deg",
    "polished",
)


def eval_row(step: int, wall: float, summary: dict[str, float], polished: bool = False) -> dict[str, Any]:
    """One ``eval.csv`` row (``EVAL_FIELDS``) from ``deck_sim.metrics.summarize``'s summary of an evaluation;
    ``polished`` marks the evaluation after ``polish_epochs`` (the same step as the last online one)."""
    return {
        "step": step,
        "wall_s": round(wall, 2),
        "episodes": int(summary["episodes"]),
        "success": summary["goal_rate"],
        "collision": summary["collision_rate"],
        "timeout": summary["timeout_rate"],
        "reward": summary["mean_reward"],
        "path_ratio": summary["path_ratio"],
        "turning_deg": summary["turning_angle_deg"],
        "polished": int(polished),
    }


RESUMABLE_CHANGES = ("total_steps", "polish_epochs", "polish_lr", "polish_hidden", "dagger_steps")
"""Config fields a resumed run may change: a longer run, or a final cloning fit or a DAgger round added to a
finished one."""


class CheckpointError(RuntimeError):
    """A checkpoint that cannot be read, or that belongs to another configuration."""


@dataclass
class _Slot:
    """One environment of the run and where it stands in its episode."""

    index: int
    stage: int = -1
    layout: ObservationLayout | None = None
    episode: int = 0
    actions: list[np.ndarray] = field(default_factory=list)
    ret: float = 0.0
    length: int = 0
    obs: np.ndarray | None = None


def _actor_meta(
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
        "config": config.to_dict(),
        "deck_sim_version": deck_sim.__version__,
        "git_commit": commit,
    }


def save_actor(path: str | os.PathLike[str], agent: DDPGAgent, meta: dict[str, Any]) -> None:
    """Write the agent's greedy actor as a weights-only ``.npz`` (atomically)."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez(tmp, meta=np.array(json.dumps(meta)), **agent.export_actor())
    os.replace(tmp, path)


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


class Trainer:
    """Trains one DDPG / MDDPG agent per ``config`` in ``run_dir``.

    Args:
        config: the run's hyperparameters.
        run_dir: folder for the logs, checkpoints and exported actors.
        resume: continue from ``run_dir/checkpoint.pt`` (its config must equal ``config`` but for ``total_steps``).
        progress: show a progress bar.
    """

    def __init__(
        self, config: TrainConfig, run_dir: str | os.PathLike[str], resume: bool = False, progress: bool = True
    ) -> None:
        self.config = config.validate()
        self.run_dir = Path(run_dir)
        self.progress = progress
        self.commit = git_commit()  # the code this process runs, whatever the tree holds when an actor is written
        self._resume_state: dict[str, Any] | None = None
        if resume:
            self._resume_state = load_checkpoint(self.run_dir / "checkpoint.pt")
            self._check_compatible(self._resume_state["config"])
        elif (self.run_dir / "checkpoint.pt").exists():
            raise CheckpointError(
                f"{self.run_dir} already holds a run (checkpoint.pt); resume it with --resume or choose another folder"
            )
        self.run_dir.mkdir(parents=True, exist_ok=True)
        cfg = self.config
        torch.set_num_threads(cfg.torch_threads)
        torch.manual_seed(cfg.seed)
        torch.use_deterministic_algorithms(True)
        self.rng = np.random.default_rng(cfg.seed)
        self.slots = [_Slot(i) for i in range(cfg.num_envs)]
        self.envs = make_runner(cfg.num_envs, cfg.env_worker)
        # the full scene fixes the layout of every observation
        probe = make_env(cfg.scene, cfg.predictor, **cfg.scene_overrides)
        self.layout = env_layout(probe)
        probe.close()
        self.obs_dim = self.layout.dim
        self.agent = DDPGAgent(self.obs_dim, 2, cfg, torch.Generator().manual_seed(cfg.seed + 1), self.layout.shapes)
        self.buffer = ReplayBuffer(cfg.buffer_size, self.obs_dim, 2)
        self.noise = make_noise(cfg.noise, cfg.num_envs, 2, cfg.noise_sigma, cfg.ou_theta)
        self.step = 0
        self.update_debt = 0.0
        self.wall = 0.0
        self.recent: deque[tuple[str, float]] = deque(maxlen=50)
        self.episodes_done = 0
        self.last_stats: dict[str, float] = {}
        self.best_success = -1.0
        self.polished = False
        """Whether the actor has had its final cloning fit (``polish_epochs``); it happens once per run."""
        self.dagger_done = 0
        """Environment steps of the DAgger rounds (``dagger_steps``) whose fit is done."""
        self._pad_fills: dict[str, float] | None = None  # left-out movers' scene-dependent fills (at first use)
        self.demo_summary: dict[str, float] = {}
        self._eval_env: Any = None
        self._tb: Any = None
        self._stop = False
        self._last_eval_step = -1
        self._started = False
        self._t_start = time.perf_counter()

    # -- configuration checks ----------------------------------------------------------------------------------
    @staticmethod
    def _comparable(saved: dict[str, Any]) -> dict[str, Any]:
        """A checkpoint's config in ``to_dict`` form (fields added since it was written take their defaults, as a
        resumed config does), or as saved where it no longer parses (its difference is then named as it stands)."""
        try:
            return TrainConfig.from_dict(saved).to_dict()
        except (ConfigError, TypeError, ValueError):
            return saved

    def _check_compatible(self, saved: dict[str, Any]) -> None:
        mine = self.config.to_dict()
        saved = self._comparable(saved)
        diff = [k for k in sorted(set(mine) | set(saved)) if k not in RESUMABLE_CHANGES and mine.get(k) != saved.get(k)]
        if diff:
            detail = "; ".join(f"{k}: checkpoint {saved.get(k)!r}, now {mine.get(k)!r}" for k in diff[:5])
            raise CheckpointError(f"{self.run_dir / 'checkpoint.pt'} was written by another configuration ({detail})")

    def _check_polished(self, saved: dict[str, Any], end: int) -> None:
        """A polished run is finished: its actor is no longer the online one, so it can be neither extended nor
        polished again with other settings."""
        if end > self.step:
            raise CheckpointError(
                f"{self.run_dir} was polished at step {self.step} (polish_epochs): it cannot be extended to {end} "
                "steps; train a new run with more steps instead"
            )
        if self.dagger_done > self.config.dagger_steps:
            raise CheckpointError(
                f"{self.run_dir} had a DAgger round of {self.dagger_done} steps (dagger_steps); it cannot be "
                f"undone to {self.config.dagger_steps}"
            )
        mine, saved, default = self.config.to_dict(), self._comparable(saved), TrainConfig().to_dict()
        for k in ("polish_epochs", "polish_lr", "polish_hidden"):
            value = saved.get(k, default[k])
            if value != mine[k]:
                raise CheckpointError(
                    f"{self.run_dir} was polished with {k} = {value!r}; it cannot be polished again with {mine[k]!r}"
                )

    # -- curriculum and environments ---------------------------------------------------------------------------
    def _stage_index(self) -> int:
        stages = self.config.curriculum
        frac = self.step / self.config.total_steps
        for i, s in enumerate(stages):
            if frac < s.until:
                return i
        return len(stages)  # past the last stage: the full scene

    def _stage(self, index: int) -> CurriculumStage | None:
        stages = self.config.curriculum
        return stages[index] if index < len(stages) else None

    def _obs(self, slot: _Slot, flat: np.ndarray) -> np.ndarray:
        if slot.layout.keys == self.layout.keys and slot.layout.shapes == self.layout.shapes:
            return flat
        if self._pad_fills is None:
            self._pad_fills = mover_pad_fills(self.config)
        return slot.layout.pad_to(flat, self.layout, self._pad_fills).astype(np.float32)

    def _start_episode(self, slot: _Slot, stage: int | None = None) -> None:
        cfg = self.config
        stage = self._stage_index() if stage is None else stage
        if slot.stage != stage:
            overrides = {**cfg.scene_overrides, **stage_overrides(cfg.scene, self._stage(stage))}
            slot.layout = self.envs.build(
                slot.index, cfg.scene, cfg.predictor, overrides, cfg.expert_relabel, cfg.teacher_body
            )
            slot.stage = stage
        obs = self.envs.reset(slot.index, train_episode_seed(cfg.seed, slot.index, slot.episode))
        slot.obs = self._obs(slot, obs)
        slot.actions, slot.ret, slot.length = [], 0.0, 0
        self.noise.reset(slot.index)

    # -- the loop -----------------------------------------------------------------------------------------------
    def train(self, stop_at: int | None = None) -> dict[str, Any]:
        """Run until ``total_steps`` (or ``stop_at``) environment steps, then checkpoint and export the actor.

        A SIGINT (Ctrl-C) stops at the next step boundary with a checkpoint, so ``--resume`` continues exactly.
        Returns the last evaluation's summary and the run's counters.
        """
        cfg = self.config
        end = min(cfg.total_steps, stop_at) if stop_at is not None else cfg.total_steps
        if self._resume_state is not None:
            saved = self._resume_state
            self._restore(saved)
            self._resume_state = None
            if self.polished:
                self._check_polished(saved["config"], end)
        # wall-clock of the run, demonstrations and pre-training included, summed over resumed sessions
        self._t_start = time.perf_counter() - self.wall
        cfg.save(self.run_dir / "config.json")  # (a resumed run may have changed RESUMABLE_CHANGES)
        if not self._started:
            self._open_csv(truncate_after=None)
            self._begin()
        self._started = True
        from torch.utils.tensorboard import SummaryWriter

        self._tb = SummaryWriter(str(self.run_dir / "tb"), purge_step=self.step or None)
        bar = tqdm(total=end, initial=self.step, desc=f"{cfg.algo} {cfg.scene}", unit="step", disable=not self.progress)
        t_log, step_log = time.perf_counter(), self.step
        last_eval: dict[str, Any] = {}
        with self._stop_on_sigint(), bar:
            while self.step < end and not self._stop:
                self._collect()
                self._tick()
                bar.update(cfg.num_envs)
                if self._crossed(cfg.log_every):
                    now = time.perf_counter()
                    sps = (self.step - step_log) / max(now - t_log, 1e-9)
                    t_log, step_log = now, self.step
                    row = self._log_progress(sps)
                    bar.set_postfix(
                        success=f"{row['success']:.0%}", reward=f"{row['ep_reward']:.0f}", q=f"{row['q']:.1f}"
                    )
                if cfg.eval_every and self._crossed(cfg.eval_every):
                    last_eval = self.evaluate()
                    bar.write(
                        f"step {self.step}: held-out success {last_eval['success']:.0%}, "
                        f"reward {last_eval['mean_reward']:.1f}"
                    )
                if cfg.checkpoint_every and self._crossed(cfg.checkpoint_every):
                    self.save_checkpoint()
        self.save_checkpoint()
        if self.step >= cfg.total_steps:
            if self._last_eval_step != self.step:
                last_eval = self.evaluate()
                self.save_checkpoint()  # (with the best success so far: a later polish is compared with it)
            owed = bool(cfg.polish_epochs) and not self.polished
            if owed and not self._stop:
                # the checkpoint is written after the polished evaluation: a run that dies before it polishes again
                self._polish()
                last_eval = self.evaluate()
                self.save_checkpoint()
                owed = False
            if not owed and self.dagger_done < cfg.dagger_steps and not self._stop:
                # no checkpoint inside the round: one stopped before its fit starts again from the fitted run
                round_eval = self._dagger_round()
                owed = round_eval is None
                last_eval = round_eval or last_eval
            if not owed:  # (a run stopped while its polish is owed is not finished: no actor.npz yet)
                meta = _actor_meta(cfg, self.layout, self.agent, self.step, self.commit, self.polished)
                save_actor(self.run_dir / "actor.npz", self.agent, meta)
        self._tb.close()
        return {
            "step": self.step,
            "wall_s": self.wall,
            "episodes": self.episodes_done,
            "eval": last_eval,
            "demonstrations": self.demo_summary,
            "stopped": self._stop,
        }

    def _dagger_round(self) -> dict[str, Any] | None:
        """Drive the fitted actor for the ``dagger_steps`` not yet done (greedy, no updates), every state labelled
        by the planner, then fit again, evaluate and checkpoint. Returns the evaluation, or None if stopped first."""
        cfg = self.config
        steps = cfg.dagger_steps - self.dagger_done
        log.info("DAgger round: the fitted actor drives %d steps, labelled by the planner", steps)
        end = self.step + steps
        bar = tqdm(total=steps, desc="DAgger round", unit="step", disable=not self.progress, leave=False)
        with self._stop_on_sigint(), bar:
            while self.step < end and not self._stop:
                self._collect(explore=False)
                self._tick()
                bar.update(cfg.num_envs)
        if self.step < end:
            log.warning("the DAgger round stopped before its fit: --resume starts it again from the fitted run")
            return None
        self._polish()
        self.dagger_done = cfg.dagger_steps
        summary = self.evaluate()
        self.save_checkpoint()
        return summary

    def _polish(self) -> None:
        """The final cloning fit on every labelled transition of the buffer (``polish_epochs``)."""
        cfg = self.config
        rows = np.flatnonzero(self.buffer.labelled[: self.buffer.size] > 0)
        obs, target = self.buffer.obs[rows], self.buffer.expert_action[rows]
        log.info("polishing the actor: %d epochs over %d labelled transitions", cfg.polish_epochs, len(rows))
        t0 = time.perf_counter()
        losses = self.agent.polish(obs, target, cfg.polish_epochs, torch.Generator().manual_seed(cfg.seed + 2))
        self._tick()
        self.polished = True
        if self._tb is not None:
            for epoch, loss in enumerate(losses):
                self._tb.add_scalar("polish/bc_loss", loss, epoch)
        log.info("polished in %.0f s: cloning loss %.4f -> %.4f", time.perf_counter() - t0, losses[0], losses[-1])

    def close(self) -> None:
        """Release the environments (and their worker process); ``train`` does so when the run ends."""
        if self.envs is not None:
            self.envs.close()
            self.envs = None

    def __del__(self) -> None:
        envs = getattr(self, "envs", None)
        if envs is not None:
            envs.close()

    def _tick(self) -> None:
        self.wall = time.perf_counter() - self._t_start

    @contextlib.contextmanager
    def _stop_on_sigint(self) -> Iterator[None]:
        """Inside: Ctrl-C sets ``_stop``, checked at every step boundary (in the main thread; elsewhere signals
        are not ours to take); the previous handler is back afterwards."""
        previous = signal.signal(signal.SIGINT, self._on_sigint) if _main_thread() else None
        try:
            yield
        finally:
            if previous is not None:
                signal.signal(signal.SIGINT, previous)

    def _on_sigint(self, signum: int, frame: Any) -> None:  # noqa: ARG002
        log.warning("interrupted: stopping at the next step with a checkpoint (resume with --resume)")
        self._stop = True

    def _crossed(self, every: int) -> bool:
        """Whether the last collection crossed a multiple of ``every`` steps."""
        n = self.config.num_envs
        return every > 0 and (self.step // every) > ((self.step - n) // every)

    def _begin(self) -> None:
        cfg = self.config
        if cfg.demo_episodes:
            demos = collect_demonstrations(
                cfg.scene,
                cfg.demo_episodes,
                cfg.seed,
                self.layout,
                self.progress,
                noise=cfg.demo_noise,
                body=cfg.teacher_body,
                **cfg.scene_overrides,
            )
            self.buffer.add_demos(
                demos.obs, demos.action, demos.reward, demos.next_obs, demos.terminated, demos.expert_action
            )
            self.agent.norm.update(demos.obs)
            self.demo_summary = {
                "episodes": demos.episodes,
                "transitions": len(demos),
                "success": demos.successes / max(demos.episodes, 1),
            }
            for _ in tqdm(
                range(cfg.pretrain_updates),
                desc="pretraining on demonstrations",
                unit="upd",
                disable=not self.progress,
                leave=False,
            ):
                self.last_stats = self.agent.update(self.buffer.sample(cfg.batch_size, self.rng), clone_only=True)
            if cfg.eval_every:  # where the demonstrations alone got the actor: the first point of the curve
                self.evaluate()
        for slot in self.slots:
            self._start_episode(slot)

    def _collect(self, explore: bool = True) -> None:
        """One step of every environment; the learner's updates run while the environments step.

        Order (the same for both runners, so that they give the same numbers): act on the current observations,
        start the step, update from the replay buffer as it stands, then store the step's transitions.
        ``explore=False`` (a DAgger round): the greedy actor acts, and neither the networks, the normaliser nor
        the noise and cloning schedules change.
        """
        cfg = self.config
        obs = np.stack([s.obs for s in self.slots])
        if not explore:
            actions = np.clip(self.agent.act(obs), -1.0, 1.0)
        elif self.step < cfg.learning_starts and not self.buffer.n_demo:
            actions = self.rng.uniform(-1.0, 1.0, (cfg.num_envs, 2))
        else:
            actions = np.clip(self.agent.act(obs) + self.noise.sample(self.rng), -1.0, 1.0)
        self.envs.step_async(actions)
        if explore:
            self._learn(self.step + cfg.num_envs)
        results = self.envs.step_wait()
        rows: dict[str, list[Any]] = {k: [] for k in ("obs", "action", "reward", "next_obs", "terminated", "expert")}
        for slot, action, res in zip(self.slots, actions, results, strict=True):
            next_obs = self._obs(slot, res.obs)
            slot.actions.append(action)
            slot.ret += res.reward
            slot.length += 1
            rows["obs"].append(slot.obs)
            rows["action"].append(action)
            rows["reward"].append(res.reward)
            rows["next_obs"].append(next_obs)  # at a truncation: the final observation, bootstrapped through
            rows["terminated"].append(float(res.terminated))  # goal, collision, off the deck: no bootstrap
            rows["expert"].append(res.expert)
            if res.terminated or res.truncated:
                self.recent.append((outcome_of(res.info, res.truncated and not res.terminated), slot.ret))
                self.episodes_done += 1
                slot.episode += 1
                self._start_episode(slot)
            else:
                slot.obs = next_obs
        batch = {k: np.asarray(v, dtype=np.float32) for k, v in rows.items() if k != "expert"}
        if explore:
            self.agent.norm.update(batch["obs"])
        expert = np.asarray(rows["expert"], dtype=np.float32) if cfg.expert_relabel else None
        self.buffer.add(batch["obs"], batch["action"], batch["reward"], batch["next_obs"], batch["terminated"], expert)
        self.step += cfg.num_envs
        if not explore:
            return
        frac = min(1.0, self.step / max(1.0, cfg.noise_decay * cfg.total_steps))
        self.noise.sigma = cfg.noise_sigma + frac * (cfg.noise_sigma_final - cfg.noise_sigma)
        self.agent.bc_weight = bc_weight_at(cfg, self.step)

    def _learn(self, step: int) -> None:
        """The updates owed once the run reaches ``step`` environment steps (``updates_per_step`` each)."""
        cfg = self.config
        if step < cfg.learning_starts or self.buffer.size == 0:
            return
        self.update_debt += cfg.num_envs * cfg.updates_per_step
        while self.update_debt >= 1.0:
            batch = self.buffer.sample(cfg.batch_size, self.rng, cfg.demo_fraction)
            stats = self.agent.update(batch)
            self.last_stats.update(stats)
            self.update_debt -= 1.0

    # -- evaluation ---------------------------------------------------------------------------------------------
    def actor_policy(self) -> LearnedPolicy:
        """The current greedy actor as the policy an exported file would give."""
        meta = _actor_meta(self.config, self.layout, self.agent, self.step, self.commit)
        return LearnedPolicy(self.agent.export_actor(), meta)

    def evaluate(self, episodes: int | None = None) -> dict[str, Any]:
        """Play ``eval_episodes`` held-out episodes (seed ``eval_seed``, the full scene) with the greedy actor."""
        cfg = self.config
        self._tick()
        if self._eval_env is None:
            self._eval_env = deck_sim.load(
                cfg.scene, seed=cfg.eval_seed, **{**cfg.scene_overrides, "episode__predictor": cfg.predictor}
            )
        env = self._eval_env
        env.random_state.seed(cfg.eval_seed)
        policy = self.actor_policy()
        results = [run_episode(env, policy, episode=k) for k in range(episodes or cfg.eval_episodes)]
        summary = summarize(results)
        row = eval_row(self.step, self.wall, summary, self.polished)
        self._last_eval_step = self.step
        self._append_csv("eval.csv", EVAL_FIELDS, row)
        if self._tb is not None:
            for k in ("success", "collision", "timeout", "reward"):
                self._tb.add_scalar(f"eval/{k}", row[k], self.step)
        summary["success"] = summary["goal_rate"]
        if summary["success"] > self.best_success:
            self.best_success = summary["success"]
            meta = _actor_meta(cfg, self.layout, self.agent, self.step, self.commit, self.polished)
            save_actor(self.run_dir / "actor_best.npz", self.agent, meta)
        return summary

    # -- logs ---------------------------------------------------------------------------------------------------
    def _open_csv(self, truncate_after: int | None) -> bool:
        """Start the CSV logs, keeping the rows up to ``truncate_after`` (a resumed run); whether ``eval.csv``
        kept a row at exactly that step."""
        evaluated = False
        for name, fields in (("progress.csv", PROGRESS_FIELDS), ("eval.csv", EVAL_FIELDS)):
            path = self.run_dir / name
            kept: list[dict[str, str]] = []
            if truncate_after is not None and path.exists():
                with open(path, newline="") as f:
                    kept = [r for r in csv.DictReader(f) if int(r["step"]) <= truncate_after]
                evaluated = evaluated or (name == "eval.csv" and any(int(r["step"]) == truncate_after for r in kept))
            with open(path, "w", newline="") as f:
                w = csv.DictWriter(f, fieldnames=fields)
                w.writeheader()
                w.writerows(kept)
        return evaluated

    def _append_csv(self, name: str, fields: tuple[str, ...], row: dict[str, Any]) -> None:
        with open(self.run_dir / name, "a", newline="") as f:
            csv.DictWriter(f, fieldnames=fields).writerow({k: row.get(k, "") for k in fields})

    def _log_progress(self, sps: float) -> dict[str, Any]:
        outcomes = [o for o, _ in self.recent]
        n = max(len(outcomes), 1)
        s = self.last_stats
        row = {
            "step": self.step,
            "episodes": self.episodes_done,
            "wall_s": round(self.wall, 2),
            "sps": round(sps, 1),
            "ep_reward": float(np.mean([r for _, r in self.recent])) if self.recent else 0.0,
            "success": outcomes.count("goal") / n,
            "collision": outcomes.count("collision") / n,
            "timeout": outcomes.count("timeout") / n,
            "critic_loss": s.get("critic_loss", float("nan")),
            "q": s.get("q", float("nan")),
            "actor_loss": s.get("actor_loss", float("nan")),
            "bc_loss": s.get("bc_loss", float("nan")),
            "noise_sigma": self.noise.sigma,
            "stage": self.slots[0].stage,
            "updates": self.agent.updates,
        }
        self._append_csv("progress.csv", PROGRESS_FIELDS, row)
        for k in ("ep_reward", "success", "collision", "timeout", "critic_loss", "q", "actor_loss", "sps"):
            self._tb.add_scalar(f"train/{k}", row[k], self.step)
        return row

    # -- checkpoints --------------------------------------------------------------------------------------------
    def save_checkpoint(self) -> Path:
        """Write ``checkpoint.pt`` atomically (a crash while writing leaves the previous one intact)."""
        state = {
            "format": CHECKPOINT_FORMAT,
            "config": self.config.to_dict(),
            "step": self.step,
            "wall": self.wall,
            "update_debt": self.update_debt,
            "episodes_done": self.episodes_done,
            "recent": [[o, float(r)] for o, r in self.recent],
            "last_stats": dict(self.last_stats),
            "best_success": self.best_success,
            "polished": self.polished,
            "dagger_done": self.dagger_done,
            "demo_summary": dict(self.demo_summary),
            "agent": self.agent.state_dict(),
            "buffer": self.buffer.state_dict(),
            "noise": self.noise.state_dict(),
            "rng": self.rng.bit_generator.state,
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
                for s in self.slots
            ],
        }
        path = self.run_dir / "checkpoint.pt"
        _atomic_torch_save(state, path)
        return path

    def _restore(self, state: dict[str, Any]) -> None:
        try:
            # a polished checkpoint holds the fit's actor, of the widths its own config gave the fit
            widths = tuple(self._comparable(state["config"]).get("polish_hidden") or ())
            if state.get("polished", False) and widths:
                self.agent.set_actor_widths(widths)
            self.agent.load_state_dict(state["agent"])
            self.buffer.load_state_dict(state["buffer"])
            self.noise.load_state_dict(state["noise"])
        except (ValueError, KeyError) as err:
            raise CheckpointError(f"{self.run_dir / 'checkpoint.pt'}: {err}") from err
        self.step = int(state["step"])
        self.agent.bc_weight = bc_weight_at(self.config, self.step)
        self.wall = float(state["wall"])
        self.update_debt = float(state["update_debt"])
        self.episodes_done = int(state["episodes_done"])
        self.recent.extend((o, float(r)) for o, r in state["recent"])
        self.last_stats = dict(state["last_stats"])
        self.best_success = float(state["best_success"])
        self.polished = bool(state.get("polished", False))  # (checkpoints from before the switch: not polished)
        self.dagger_done = int(state.get("dagger_done", 0))
        self.demo_summary = dict(state["demo_summary"])
        self.rng.bit_generator.state = state["rng"]
        for slot, saved in zip(self.slots, state["slots"], strict=True):
            slot.episode = int(saved["episode"])
            self._start_episode(slot, stage=int(saved["stage"]))
            actions = saved["actions"].numpy()
            if len(actions):  # replay the episode so far: same seed, same actions, same state (planner included)
                seed = train_episode_seed(self.config.seed, slot.index, slot.episode)
                slot.obs = self._obs(slot, self.envs.replay(slot.index, seed, actions))
                slot.actions = list(actions)
            if not np.array_equal(slot.obs, saved["obs"].numpy()):
                raise CheckpointError(
                    f"environment {slot.index} did not replay to its checkpointed state: the scene or deck_sim "
                    "changed since the checkpoint was written"
                )
            slot.ret, slot.length = float(saved["ret"]), int(saved["length"])
        self.noise.load_state_dict(state["noise"])  # _start_episode reset it
        torch.set_rng_state(state["torch_rng"])
        if self._open_csv(truncate_after=self.step):
            self._last_eval_step = self.step  # the run's evaluation at this step is on file already
        self._started = True
        log.info("resumed %s at step %d", self.run_dir, self.step)


def _main_thread() -> bool:
    import threading

    return threading.current_thread() is threading.main_thread()


def shipped_actor(run_dir: str | os.PathLike[str]) -> Path:
    """The actor file of a finished run that ``scripts/train_shipped.py`` ships.

    A run whose final ``actor.npz`` is the cloning fit's (its own record says ``polished``) ships that file; any
    other run (stable-baselines3's, or one without the fit) the actor of its best periodic evaluation,
    ``actor_best.npz``. Picking the best of ten 100-episode evaluations picks noise (a 95 % interval of +-7 points
    near 85 % success): in the five deck runs measured where the two differ, the final actor was within a point
    or up to 6 points better on 400 held-out episodes (``docs/training.md``, the best of ten evaluations against
    the final actor).
    """
    run = Path(run_dir)
    final = run / "actor.npz"
    if final.exists() and LearnedPolicy.load(final).meta.get("polished", False):
        return final
    return run / "actor_best.npz"


def config_from_checkpoint(run_dir: str | os.PathLike[str]) -> TrainConfig:
    """The configuration stored in ``run_dir/checkpoint.pt`` (for ``--resume`` without repeating the options)."""
    state = load_checkpoint(Path(run_dir) / "checkpoint.pt")
    try:
        return TrainConfig.from_dict(state["config"])
    except ConfigError as err:
        raise CheckpointError(f"{run_dir}/checkpoint.pt: its config is not valid here: {err}") from err

"""One readable training loop for DDPG / MDDPG: collect, learn, evaluate (``Trainer``).

A run lives in one folder:
    config.json        the ``TrainConfig`` (every hyperparameter)
    progress.csv       training statistics every ``log_every`` steps (episode reward, success, collision and
                       timeout rates over the last 50 episodes, critic loss, Q, actor loss, steps per second)
    eval.csv           held-out evaluations (success, collision, timeout, reward, path ratio, turning angle)
    tb/                the same curves for TensorBoard
    checkpoint.pt      everything needed to continue exactly (networks, optimisers, replay, noise, RNG states,
                       each environment's episode seed and the actions taken in it); written atomically, with
                       its SHA-256 checksum (``training.checkpoints``)
    checkpoint.prev.pt the checkpoint before it
    actor.npz          the final greedy actor, weights only (``deck_sim.policies.LearnedPolicy``)
    actor_best.npz     the actor of the best evaluation so far
    actor_avg.npz      the final slow average of the actor (``actor_average``; absent when off)
    actor_avg_select.npz  that average choosing by the run's critic (``training.final_fit.played_actor``; made
                       when the run is first measured or shipped that way)
    heldout_<N>.json   the shipped actor on N held-out episodes (``training.heldout``; and
                       ``heldout_<N>_<play>.json`` for another way of acting)

The trainer's collaborators each own one job: ``training.runlog`` the CSV and TensorBoard logs,
``training.checkpoints`` the checkpoint and the exact resume, ``training.final_fit`` the final cloning fit, the
DAgger round and the exported actor files. Their names are importable from here as well.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

import deck_sim
from deck_sim.metrics import outcome_of, summarize
from deck_sim.policies import LearnedPolicy
from deck_sim.progress import progress as progress_report
from deck_sim.rollout import git_commit, run_episode
from deck_sim.scenes import load_scene
from training.buffers import EpisodeMarks, ReplayBuffer
from training.checkpoints import (
    CHECKPOINT,
    CHECKPOINT_FORMAT,
    PREVIOUS,
    RESUMABLE_CHANGES,
    CheckpointError,
    acting_workers,
    check_budget,
    check_compatible,
    check_polished,
    config_from_checkpoint,
    load_checkpoint,
    load_run_checkpoint,
    restore,
    save_checkpoint,
)
from training.config import ConfigError, CurriculumStage, TrainConfig, bc_weight_at, train_episode_seed
from training.ddpg import DDPGAgent
from training.envs import (
    Demonstrations,
    ObservationLayout,
    collect_demonstrations,
    composer_layout,
    stage_overrides,
)
from training.final_fit import actor_meta, finish, save_actor, shipped_actor
from training.her import ROUTE_REFUSAL, GoalGeometry, GoalLayoutError, HindsightSampler
from training.noise import HeldActions, make_noise
from training.runlog import EVAL_FIELDS, PROGRESS_FIELDS, EpisodeStats, RunLog, eval_row, progress_row
from training.runners import AgentView, EnvSpec, StepOrder, make_runner

log = logging.getLogger(__name__)

__all__ = [
    "CHECKPOINT_FORMAT",
    "EVAL_FIELDS",
    "PROGRESS_FIELDS",
    "RESUMABLE_CHANGES",
    "CheckpointError",
    "Trainer",
    "config_from_checkpoint",
    "eval_row",
    "load_checkpoint",
    "save_actor",
    "shipped_actor",
]


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


class Trainer:
    """Trains one DDPG / MDDPG agent per ``config`` in ``run_dir``.

    Args:
        config: the run's hyperparameters.
        run_dir: folder for the logs, checkpoints and exported actors.
        resume: continue from ``run_dir/checkpoint.pt`` (its config must equal ``config`` but for
            ``RESUMABLE_CHANGES``, and ``total_steps`` may not fall below the steps the run has done).
        progress: show a progress bar.
        backend: where the environments step (``training.runners``): ``local`` or ``ray``.
        workers: worker processes (``local``; 0 steps inline) or Ray actors (``ray``), each holding a contiguous
            group of the environments and acting for it; None: one worker where ``config.env_worker`` asks for it
            (none otherwise) on ``local``, one actor on ``ray``, or a resumed run's own count of groups. The count
            of acting groups, ``max(workers, 1)``, is part of what the run's numbers depend on; the checkpoint
            keeps it and a resumed run must act in as many.
        ray_address: the Ray cluster of ``ray`` (None: a local one).
    """

    slot_class: type[_Slot] = _Slot
    """What each environment's slot records (a subclass may record more)."""
    several_aircraft: bool = False
    """Whether the trainer takes scenes of several aircraft (``training.team.TeamTrainer``)."""

    def __init__(
        self,
        config: TrainConfig,
        run_dir: str | os.PathLike[str],
        resume: bool = False,
        progress: bool = True,
        backend: str = "local",
        workers: int | None = None,
        ray_address: str | None = None,
    ) -> None:
        self.config = config.validate()
        scene = load_scene(config.scene, **config.scene_overrides)  # (checked before the run folder is made)
        if scene.multi_agent and not self.several_aircraft:
            raise ConfigError(f"scene {config.scene!r} puts several aircraft on the deck: train it with "
                              "training.team.TeamTrainer (deck-sim train and training.team.make_trainer pick it)")
        if config.her_ratio > 0.0 and scene.episode.route_steps > 0:
            raise ConfigError(f"her_ratio: {ROUTE_REFUSAL}")
        self.run_dir = Path(run_dir)
        self.progress = progress
        self.commit = git_commit()  # the code this process runs, whatever the tree holds when an actor is written
        self._resume_state: dict[str, Any] | None = None
        if resume:
            self._resume_state = load_run_checkpoint(self.run_dir)
            check_compatible(self.config, self._resume_state["config"], self.run_dir / CHECKPOINT)
            check_budget(self.config.total_steps, self._resume_state, self.run_dir / CHECKPOINT)
        else:
            for name in (CHECKPOINT, PREVIOUS):
                if (self.run_dir / name).exists():
                    raise CheckpointError(
                        f"{self.run_dir} already holds a run ({name}); resume it with --resume or choose another "
                        "folder"
                    )
        self.run_dir.mkdir(parents=True, exist_ok=True)
        cfg = self.config
        torch.set_num_threads(cfg.torch_threads)
        torch.manual_seed(cfg.seed)
        torch.use_deterministic_algorithms(True)
        self.rng = np.random.default_rng(cfg.seed)
        self.slots = [self.slot_class(i) for i in range(cfg.num_envs)]
        self.collected = cfg.num_envs
        """Environment steps (transitions) the last collection added."""
        self._eval_env: Any = None
        self.layout = self._agent_layout()
        self.workers = acting_workers(cfg, backend, workers, self._resume_state, self.run_dir / CHECKPOINT)
        self.envs: Any = None
        self.envs = self._make_envs(backend, ray_address)
        self.agent = DDPGAgent(self.obs_dim, 2, cfg, torch.Generator().manual_seed(cfg.seed + 1), self.layout.shapes)
        tracking = cfg.her_ratio > 0.0 or cfg.n_step > 1
        self.buffer = ReplayBuffer(
            cfg.buffer_size, self.obs_dim, 2, track_episodes=tracking, prioritised=cfg.per_alpha > 0.0
        )
        self.hindsight = self._hindsight_sampler() if tracking else None
        """Hindsight targets and n-step returns for the learner's batches (``training.her``), or None."""
        self.noise = make_noise(cfg.noise, self._noise_rows(), 2, cfg.noise_sigma, cfg.ou_theta)
        self.hold = HeldActions(self._noise_rows(), 2, cfg.hold_prob, cfg.hold_steps, cfg.hold_action)
        self.runlog = RunLog(self.run_dir)
        self.stats = EpisodeStats()
        self.step = 0
        """Environment steps collected so far, summed over the environments."""
        self.update_debt = 0.0
        self.wall = 0.0
        """Wall-clock seconds of the run, demonstrations and pre-training included, summed over resumed processes."""
        self.best_success = -1.0
        self.polished = False
        """Whether the actor has had its final cloning fit (``polish_epochs``); it happens once per run."""
        self.dagger_done = 0
        """Environment steps of the DAgger rounds (``dagger_steps``) whose fit is done."""
        self.demo_summary: dict[str, float] = {}
        self.last_eval_step = -1
        self._specs: dict[int, EnvSpec] = {}
        self._real_masks: dict[int, np.ndarray] = {}  # per curriculum stage: ``_real_mask``
        self._stop = False
        self._started = False
        self._t_start = time.perf_counter()

    def _hindsight_sampler(self) -> HindsightSampler:
        cfg = self.config
        geometry = None
        if cfg.her_ratio > 0.0:
            try:
                geometry = GoalGeometry.of(load_scene(cfg.scene, **cfg.scene_overrides), self.layout.shapes)
            except GoalLayoutError as err:
                raise ConfigError(f"her_ratio: {err}") from None
        return HindsightSampler(geometry, cfg.her_ratio, cfg.n_step, cfg.gamma)

    def _agent_layout(self) -> ObservationLayout:
        """The layout of the agent's observation: the full scene's (every curriculum stage is padded to it), read
        from the held-out episodes' environment, which is the full scene with the agent's predictor (built once)."""
        return composer_layout(self._eval_environment())

    def _make_envs(self, backend: str, ray_address: str | None) -> Any:
        """The runner of the run's environments (``training.runners``)."""
        cfg = self.config
        return make_runner(cfg.num_envs, self.workers, AgentView(self.layout, cfg), backend, ray_address)

    def _noise_rows(self) -> int:
        """How many actors explore at once (one noise process each)."""
        return self.config.num_envs

    @property
    def obs_dim(self) -> int:
        """Length of the agent's flat observation (the full scene's layout)."""
        return self.layout.dim

    # -- curriculum and environments ---------------------------------------------------------------------------
    def _stage_index(self) -> int:
        stages = self.config.curriculum
        frac = self.step / self.config.total_steps
        for i, s in enumerate(stages):
            if frac < s.until:
                return i
        return len(stages)  # past the last stage: the full scene

    def _real_mask(self, slot: _Slot) -> np.ndarray:
        """(obs_dim,) booleans: the entries of ``slot``'s current observation that its scene fills, False on the
        rows padded for the movers its curriculum stage leaves out (``ObservationLayout.real_mask``)."""
        if slot.layout is None or slot.layout.dim == self.layout.dim:
            return np.ones(self.layout.dim, dtype=bool)
        if slot.stage not in self._real_masks:
            self._real_masks[slot.stage] = slot.layout.real_mask(self.layout)
        return self._real_masks[slot.stage]

    def _stage(self, index: int) -> CurriculumStage | None:
        stages = self.config.curriculum
        return stages[index] if index < len(stages) else None

    def env_spec(self, stage: int) -> EnvSpec:
        """What an environment of curriculum ``stage`` is built from."""
        if stage not in self._specs:
            cfg = self.config
            overrides = {**cfg.scene_overrides, **stage_overrides(cfg.scene, self._stage(stage), cfg.scene_overrides)}
            self._specs[stage] = EnvSpec(
                cfg.scene, cfg.predictor, overrides, cfg.expert_relabel, cfg.teacher_body, cfg.teacher_policy_view
            )
        return self._specs[stage]

    def start_episode(self, slot: _Slot, stage: int | None = None) -> None:
        """Reset ``slot``'s environment for its next episode (rebuilt first when its curriculum ``stage``, by default
        the current one, changed) and its exploration noise."""
        stage = self._stage_index() if stage is None else stage
        if slot.stage != stage:
            slot.layout = self.envs.build(slot.index, *self.env_spec(stage))
            slot.stage = stage
        seed = train_episode_seed(self.config.seed, slot.index, slot.episode)
        self._enter_episode(slot, self.envs.reset(slot.index, seed))

    def _enter_episode(self, slot: _Slot, obs: np.ndarray) -> None:
        """``slot``'s episode starts at ``obs`` (the agent's layout): its record and its exploration noise anew."""
        slot.obs = obs
        slot.actions, slot.ret, slot.length = [], 0.0, 0
        self.noise.reset(slot.index)
        self.hold.reset(slot.index)

    # -- the loop -----------------------------------------------------------------------------------------------
    def train(self, stop_at: int | None = None) -> dict[str, Any]:
        """Run until ``total_steps`` (or ``stop_at``) environment steps, then checkpoint and, at ``total_steps``,
        make the final fit and the DAgger round the config asks for and export the actor (``final_fit.finish``).

        A SIGINT (Ctrl-C) stops at the next step boundary with a checkpoint, so ``--resume`` continues exactly.
        Returns the last evaluation's summary and the run's counters.
        """
        cfg = self.config
        end = min(cfg.total_steps, stop_at) if stop_at is not None else cfg.total_steps
        if self._resume_state is not None:
            saved = self._resume_state
            restore(self, saved)
            self._started = True
            self._resume_state = None
            if self.polished:
                check_polished(self, saved["config"], end)
        # wall-clock of the run, demonstrations and pre-training included, summed over resumed processes
        self._t_start = time.perf_counter() - self.wall
        cfg.save(self.run_dir / "config.json")  # (a resumed run may have changed RESUMABLE_CHANGES)
        self.runlog.open_tensorboard(self.step)
        if not self._started:
            self.runlog.open_csv(truncate_after=None)
            self._begin()
        self._started = True
        bar = progress_report(
            total=end, initial=self.step, desc=f"{cfg.algo} {cfg.scene}", unit="step", disable=not self.progress
        )
        t_log, step_log = time.perf_counter(), self.step
        last_eval: dict[str, Any] = {}
        with self.stop_on_sigint(), bar:
            while self.step < end and not self._stop:
                self.collect()
                self._tick()
                bar.update(self.collected)
                if self._crossed(cfg.log_every):
                    now = time.perf_counter()
                    sps = (self.step - step_log) / max(now - t_log, 1e-9)
                    t_log, step_log = now, self.step
                    row = progress_row(
                        self.stats, self.step, self.wall, sps, self.noise.sigma, self.slots[0].stage,
                        self.agent.updates,
                    )
                    self.runlog.progress(row)
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
            self.save_checkpoint()  # (still inside: a second Ctrl-C while it writes only asks to stop again)
        if self.step >= cfg.total_steps:
            last_eval = finish(self, last_eval)
        self.runlog.close_tensorboard()
        return {
            "step": self.step,
            "wall_s": self.wall,
            "episodes": self.stats.episodes,
            "eval": last_eval,
            "demonstrations": self.demo_summary,
            "stopped": self._stop,
        }

    def save_checkpoint(self) -> Path:
        """Write ``checkpoint.pt`` atomically with its checksum (a crash while writing leaves the previous one
        intact), the one it replaces kept as ``checkpoint.prev.pt``."""
        return save_checkpoint(self)

    def slot_states(self) -> list[dict[str, Any]]:
        """What the checkpoint keeps of every environment: its episode, stage, return and length so far, the
        actions taken in the episode (replayed on resume; rows of 2, several aircraft's joint actions one after
        another) and its current observation (the replay's check)."""
        return [
            {
                "episode": s.episode,
                "stage": s.stage,
                "ret": float(s.ret),
                "length": int(s.length),
                "actions": torch.from_numpy(np.asarray(s.actions, dtype=np.float64).reshape(-1, 2)),
                "obs": torch.from_numpy(np.array(s.obs, dtype=np.float32)),  # (a Ray actor's are read-only)
            }
            for s in self.slots
        ]

    def restore_slots(self, states: list[dict[str, Any]]) -> None:
        """Put every environment back where ``slot_states`` found it: its episode replayed from its seed with the
        recorded actions; ``CheckpointError`` if the replay does not reach the recorded observation."""
        for slot, saved in zip(self.slots, states, strict=True):
            slot.episode = int(saved["episode"])
            self.start_episode(slot, stage=int(saved["stage"]))
            actions = saved["actions"].numpy()
            if len(actions):  # replay the episode so far: same seed, same actions, same state (planner included)
                seed = train_episode_seed(self.config.seed, slot.index, slot.episode)
                slot.obs = self.envs.replay(slot.index, seed, actions)
                slot.actions = list(actions)
            if not np.array_equal(slot.obs, saved["obs"].numpy()):
                raise CheckpointError(
                    f"environment {slot.index} did not replay to its checkpointed state: the scene or deck_sim "
                    "changed since the checkpoint was written"
                )
            slot.ret, slot.length = float(saved["ret"]), int(saved["length"])

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
    def stop_on_sigint(self) -> Iterator[None]:
        """Inside: Ctrl-C sets ``_stop``, checked at every step boundary (in the main thread; elsewhere signals
        are not ours to take); the previous handler is back afterwards."""
        main_thread = threading.current_thread() is threading.main_thread()
        previous = signal.signal(signal.SIGINT, self._on_sigint) if main_thread else None
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
        n = self.collected
        return every > 0 and (self.step // every) > ((self.step - n) // every)

    def _begin(self) -> None:
        """A new run's start: the planner's demonstrations into the buffer, pre-training on them and the
        evaluation of where they got the actor (step 0), then every environment's first episode."""
        cfg = self.config
        if cfg.demo_episodes:
            demos = self._demonstrations()
            self.buffer.add_demos(
                demos.obs, demos.action, demos.reward, demos.next_obs, demos.terminated, demos.expert_action
            )
            self.agent.norm.update(demos.obs)
            self.demo_summary = {
                "episodes": demos.episodes,
                "transitions": len(demos),
                "success": demos.successes / max(demos.episodes, 1),
            }
            for _ in progress_report(
                range(cfg.pretrain_updates),
                desc="pretraining on demonstrations",
                unit="upd",
                disable=not self.progress,
                leave=False,
            ):
                self.stats.updates = self.agent.update(self.buffer.sample(cfg.batch_size, self.rng), clone_only=True)
            if cfg.eval_every:  # where the demonstrations alone got the actor: the first point of the curve
                self.evaluate()
        for slot in self.slots:
            self.start_episode(slot)

    def _demonstrations(self) -> Demonstrations:
        """The planner's ``demo_episodes`` demonstrated episodes (``training.envs.collect_demonstrations``)."""
        cfg = self.config
        return collect_demonstrations(
            cfg.scene,
            cfg.demo_episodes,
            cfg.seed,
            self.layout,
            self.progress,
            noise=cfg.demo_noise,
            body=cfg.teacher_body,
            view=cfg.teacher_policy_view,
            **cfg.scene_overrides,
        )

    def collect(self, explore: bool = True) -> None:
        """One step of every environment; the learner's updates run while the environments step.

        Order (the same for every runner, so that they give the same numbers; ``training.runners``): draw the
        step's random actions or exploration noise, start the step (each group of environments acts on its
        current observations, steps, and resets where an episode ended), update from the replay buffer as it
        stands, then store the step's transitions. ``explore=False`` (a DAgger round): the greedy actor acts, and
        neither the networks, the normaliser nor the noise and cloning schedules change.
        """
        cfg = self.config
        if not explore:
            order = StepOrder(policy=self.agent.acting())
        elif self.step < cfg.learning_starts and not self.buffer.n_demo:
            order = StepOrder(actions=self.rng.uniform(-1.0, 1.0, (cfg.num_envs, 2)))
        else:
            noise = self.noise.sample(self.rng)
            order = StepOrder(noise=noise, policy=self.agent.acting(), hold=self.hold.sample(self.rng))
        stage = self._stage_index()
        spec = None if all(s.stage == stage for s in self.slots) else self.env_spec(stage)
        order.seeds = [self._next_seed(s) for s in self.slots]
        order.builds = [None if s.stage == stage else spec for s in self.slots]
        self.envs.step_async(order)
        if explore:
            self._learn(self.step + cfg.num_envs)
        results = self.envs.step_wait()
        rows: dict[str, list[Any]] = {k: [] for k in ("obs", "action", "reward", "next_obs", "terminated", "expert")}
        marks: dict[str, list[Any]] = {k: [] for k in ("episode", "step", "reached", "failed", "goal_ok", "end")}
        real: list[np.ndarray] = []  # with a curriculum: which entries of each row are not padding
        for slot, res in zip(self.slots, results, strict=True):
            action, next_obs = res.action, res.obs
            if self.buffer.track_episodes:
                info = res.info
                marks["episode"].append(slot.episode * cfg.num_envs + slot.index)  # unique to the run
                marks["step"].append(slot.length)
                marks["reached"].append(float(bool(info.get("reached_goal"))))
                failed = info.get("collision") is not None or info.get("left_surface") or info.get("diverged")
                marks["failed"].append(float(bool(failed)))
                marks["goal_ok"].append(0.0 if info.get("diverged") else 1.0)
                marks["end"].append(float(res.terminated or res.truncated))
            slot.actions.append(action)
            slot.ret += res.reward
            slot.length += 1
            rows["obs"].append(slot.obs)
            if cfg.curriculum:
                real.append(self._real_mask(slot))
            rows["action"].append(action)
            rows["reward"].append(res.reward)
            rows["next_obs"].append(next_obs)  # at a truncation: the final observation, bootstrapped through
            rows["terminated"].append(float(res.terminated))  # goal, collision, off the deck: no bootstrap
            rows["expert"].append(res.expert)
            if res.terminated or res.truncated:
                self.stats.episode_end(outcome_of(res.info, res.truncated and not res.terminated), slot.ret)
                slot.episode += 1
                if res.reset_obs is None:
                    self.start_episode(slot, stage)
                else:  # reset (and rebuilt for the stage) by its runner within the step
                    if res.shapes is not None:
                        slot.layout, slot.stage = ObservationLayout(res.shapes), stage
                    self._enter_episode(slot, res.reset_obs)
            else:
                slot.obs = next_obs
        batch = {k: np.asarray(v, dtype=np.float32) for k, v in rows.items() if k != "expert"}
        if explore:  # (the rows a curriculum stage pads for its left-out movers stand for nothing: left out)
            self.agent.norm.update(batch["obs"], np.stack(real) if real else None)
        expert = np.asarray(rows["expert"], dtype=np.float32) if cfg.expert_relabel else None
        episode_marks = EpisodeMarks(**{k: np.asarray(v) for k, v in marks.items()}) if marks["episode"] else None
        self.buffer.add(
            batch["obs"], batch["action"], batch["reward"], batch["next_obs"], batch["terminated"], expert,
            episode_marks,
        )
        self.step += cfg.num_envs
        if explore:
            self._schedule()

    def _schedule(self) -> None:
        """The exploration noise and the cloning weight for the run's step count."""
        cfg = self.config
        frac = min(1.0, self.step / max(1.0, cfg.noise_decay * cfg.total_steps))
        self.noise.sigma = cfg.noise_sigma + frac * (cfg.noise_sigma_final - cfg.noise_sigma)
        self.agent.bc_weight = bc_weight_at(cfg, self.step)

    def _next_seed(self, slot: _Slot) -> int | None:
        """The reset seed of ``slot``'s next episode, or None where there is none (the last one's reset fails
        as it starts, outside the step)."""
        try:
            return train_episode_seed(self.config.seed, slot.index, slot.episode + 1)
        except ConfigError:
            return None

    def _learn(self, step: int, new: int | None = None) -> None:
        """The updates owed once the run reaches ``step`` environment steps, ``new`` of them (by default
        ``num_envs``) in this collection (``updates_per_step`` each)."""
        cfg = self.config
        if step < cfg.learning_starts or self.buffer.size == 0:
            return
        self.update_debt += (cfg.num_envs if new is None else new) * cfg.updates_per_step
        while self.update_debt >= 1.0:
            weights = None
            if self.buffer.prioritised:
                beta = cfg.per_beta + (1.0 - cfg.per_beta) * min(1.0, step / cfg.total_steps)
                rows, weights = self.buffer.prioritised_rows(cfg.batch_size, self.rng, cfg.demo_fraction, beta)
            else:
                rows = self.buffer.sample_rows(cfg.batch_size, self.rng, cfg.demo_fraction)
            if self.hindsight is None:
                batch = self.buffer.batch(rows)
            else:
                batch = self.hindsight.batch(self.buffer, rows, self.rng)
            if weights is not None:
                batch = batch._replace(weight=torch.from_numpy(weights))
            stats = self.agent.update(batch)
            if weights is not None:
                self.buffer.update_priorities(rows, self.agent.last_td_error, cfg.per_alpha, cfg.per_eps)
            self.stats.updates.update(stats)
            self.update_debt -= 1.0

    # -- evaluation ---------------------------------------------------------------------------------------------
    def actor_policy(self) -> LearnedPolicy:
        """The current greedy actor as the policy an exported file would give."""
        meta = actor_meta(self.config, self.layout, self.agent, self.step, self.commit)
        return LearnedPolicy(self.agent.export_actor(), meta)

    def evaluate(self, episodes: int | None = None) -> dict[str, Any]:
        """Play ``eval_episodes`` held-out episodes (seed ``eval_seed``, the full scene) with the greedy actor; log
        them, and export the actor as ``actor_best.npz`` when it beats every earlier evaluation's success."""
        cfg = self.config
        self._tick()
        summary = self._held_out(episodes or cfg.eval_episodes)
        self.last_eval_step = self.step
        self.runlog.evaluation(eval_row(self.step, self.wall, summary, self.polished))
        summary["success"] = summary["goal_rate"]
        if summary["success"] > self.best_success:
            self.best_success = summary["success"]
            meta = actor_meta(cfg, self.layout, self.agent, self.step, self.commit, self.polished)
            save_actor(self.run_dir / "actor_best.npz", self.agent, meta)
        return summary

    def _eval_environment(self) -> Any:
        """The held-out episodes' composer environment (the full scene, the agent's predictor), reseeded with
        ``eval_seed``."""
        cfg = self.config
        if self._eval_env is None:
            self._eval_env = deck_sim.load(
                cfg.scene, seed=cfg.eval_seed, **{**cfg.scene_overrides, "episode__predictor": cfg.predictor}
            )
        self._eval_env.random_state.seed(cfg.eval_seed)
        return self._eval_env

    def _held_out(self, episodes: int) -> dict[str, float]:
        """``deck_sim.metrics.summarize`` of ``episodes`` held-out episodes of the greedy actor."""
        env, policy = self._eval_environment(), self.actor_policy()
        return summarize([run_episode(env, policy, episode=k) for k in range(episodes)])

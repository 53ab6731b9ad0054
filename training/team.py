"""Shared-parameter DDPG / MDDPG for several aircraft at once (``deck1-multi``, ``deck2-multi``): ``TeamTrainer``.

One actor acts for every aircraft of every environment, each on its own observation (the single-agent keys, its
movers and the other aircraft among its dynamic obstacles), and every aircraft's transitions go into one replay
buffer. An environment is one multi-aircraft episode: an aircraft that is done (at its target, collided, off the
deck) gives its last, terminal transition and then waits, with no more transitions, until the episode ends (every
aircraft done, or the time limit, which truncates the ones still taxiing). The step counts of the run (``step``,
``total_steps``, ``learning_starts``, the logging and evaluation periods) count aircraft transitions, so a budget
means as many transitions as it does for one aircraft; ``updates_per_step`` is per transition too.

The regimes are those of one aircraft (``deck_sim.policies.regimes``): ``reward`` learns from every aircraft's
reward alone; ``oracle-teacher`` is taught by the full-knowledge prioritised planner
(``deck_sim.policies.PrioritisedPolicy``), which labels every aircraft's steps and plays the demonstrations;
``planner`` by every aircraft's scripted planner on that aircraft's observation alone
(``deck_sim.policies.IndependentPolicy`` with the config's ``teacher_policy_view``). What the single-agent loop
adds that needs one aircraft per environment is refused (a curriculum, hindsight targets, n-step returns, Ray); the
environments step in the learner's process (a config's ``env_worker`` is not read).

Held-out evaluations play ``eval_episodes`` episodes and count aircraft: ``success`` in ``eval.csv`` is the share
of aircraft that reached their targets; the share of episodes in which every aircraft arrived goes to TensorBoard
as ``eval/all_reached``. Resuming replays every environment's episode so far, as the single-agent loop does.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np

import deck_sim
from deck_sim.metrics import outcome_of, summarize, summarize_team
from deck_sim.policies import IndependentPolicy, PrioritisedPolicy, SharedPolicy
from deck_sim.progress import progress as progress_report
from deck_sim.rollout import run_team_episode
from deck_sim.scenes import load_scene
from training.checkpoints import CheckpointError
from training.config import ConfigError, TrainConfig, demo_episode_seed, train_episode_seed
from training.envs import TEACHER_PREDICTOR, Demonstrations, ObservationLayout
from training.loop import Trainer, _Slot

log = logging.getLogger(__name__)

__all__ = ["TeamEnvs", "TeamTrainer", "is_multi_agent", "make_trainer"]


def is_multi_agent(config: TrainConfig) -> bool:
    """Whether ``config``'s scene (with its overrides) has several aircraft."""
    return load_scene(config.scene, **config.scene_overrides).multi_agent


def make_trainer(config: TrainConfig, run_dir: str | os.PathLike[str], **kwargs: Any) -> Trainer:
    """The trainer for ``config``: ``TeamTrainer`` for a multi-aircraft scene, ``Trainer`` otherwise."""
    cls = TeamTrainer if is_multi_agent(config) else Trainer
    return cls(config, run_dir, **kwargs)


class TeamEnvs:
    """``n`` multi-aircraft environments stepped in the learner's process, each with its teacher (``teacher``)
    when a planner labels the aircraft's steps.

    Observations are flat float32 rows (k, ``layout.dim``), one per aircraft, in ``layout``'s key order (the
    single-agent Gymnasium adapter's flattening), so an exported actor reads them as ``LearnedPolicy`` does.

    Args:
        n: environments.
        config: the run's config (scene, overrides, predictor, whether and how the planner teaches).
        layout: the agent's observation layout.
    """

    def __init__(self, n: int, config: TrainConfig, layout: ObservationLayout) -> None:
        self.config, self.layout = config, layout
        expert = config.expert_relabel or config.demo_episodes > 0
        # an agent without prediction is taught on the teacher's forecasts and sees them dropped, as for one aircraft
        self.predictor = TEACHER_PREDICTOR if expert and config.predictor == "none" else config.predictor
        self.envs = [self.make_env() for _ in range(n)]
        self.teachers = [self.teacher(env) if config.expert_relabel else None for env in self.envs]
        self.k = self.envs[0].task.n_agents
        self.names = self.envs[0].task.agent_names

    def make_env(self) -> Any:
        """A composer environment of the run's scene with the environments' predictor."""
        cfg = self.config
        return deck_sim.load(cfg.scene, **{**cfg.scene_overrides, "episode__predictor": self.predictor})

    def teacher(self, env: Any) -> PrioritisedPolicy | IndependentPolicy:
        """The teacher of ``env`` (``TrainConfig.teacher_body`` for every aircraft's planner): the full-knowledge
        prioritised planner, or, where the teacher reads the observation (``teacher_view``, the ``planner``
        regime), every aircraft's scripted planner on its own observation (``IndependentPolicy``; sharing plans
        would tell each aircraft what its observation does not hold)."""
        cfg = self.config
        if cfg.teacher_policy_view == "full":
            return PrioritisedPolicy(env, body=cfg.teacher_body)
        return IndependentPolicy(env, view=cfg.teacher_policy_view, body=cfg.teacher_body)

    def flatten(self, observation: dict[str, np.ndarray]) -> np.ndarray:
        """Every aircraft's flat observation (k, dim) float32 from a composer observation."""
        return np.stack(
            [
                np.concatenate([np.ravel(observation[f"{name}:{key}"]) for key in self.layout.keys])
                for name in self.names
            ]
        ).astype(np.float32)

    def reset(self, i: int, seed: int) -> np.ndarray:
        """Start environment ``i``'s episode reset with ``seed``; every aircraft's first observation (k, dim)."""
        env = self.envs[i]
        env.random_state.seed(seed)
        ts = env.reset()
        if self.teachers[i] is not None:
            self.teachers[i].reset()
        return self.flatten(ts.observation)

    def step(self, i: int, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[dict[str, Any]], bool,
                                                         np.ndarray | None]:
        """Step environment ``i`` with every aircraft's action (k, 2) (a done aircraft's row is not read).

        Returns the next observations (k, dim), the rewards (k,), every aircraft's record (``last_info["agents"]``
        with the episode's ``diverged`` flag), whether the episode ended, and the planner's actions (k, 2) in
        the state the step started from (None without a teacher)."""
        env, teacher = self.envs[i], self.teachers[i]
        expert = None if teacher is None else np.clip(teacher.act({}), -1.0, 1.0)
        ts = env.step(np.asarray(actions, dtype=np.float64))
        info = env.task.last_info
        agents = [{**a, "diverged": bool(info["diverged"]) and not a["done"]} for a in info["agents"]]
        return self.flatten(ts.observation), np.asarray(ts.reward, dtype=np.float64), agents, ts.last(), expert

    def close(self) -> None:
        for env in self.envs:
            env.close()


@dataclass
class _TeamSlot(_Slot):
    """One multi-aircraft environment: ``obs`` (k, dim), ``actions`` one (k, 2) row per step so far, and per
    aircraft whether it still taxis and its return so far."""

    live: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    returns: np.ndarray = field(default_factory=lambda: np.zeros(0))


def _refused(config: TrainConfig) -> list[str]:
    """What ``config`` asks for that the shared training of several aircraft does not take."""
    bad = []
    if config.curriculum:
        bad.append("a curriculum (its stages leave movers out of one aircraft's scene)")
    if config.her_ratio > 0.0:
        bad.append("hindsight targets (her_ratio)")
    if config.n_step > 1:
        bad.append("n-step returns (n_step)")
    if config.hold_prob > 0.0:
        bad.append("held actions (hold_prob)")
    if config.actor_average > 0.0:
        bad.append("the averaged actor (actor_average)")
    return bad


class TeamTrainer(Trainer):
    """Trains one shared DDPG / MDDPG actor for every aircraft of a multi-aircraft scene (see the module).

    Args are ``Trainer``'s (by keyword after ``run_dir``); ``backend`` must be ``local`` and ``workers`` None or 0
    (the environments step in the learner's process).

    Raises:
        ConfigError: the scene has one aircraft, or the config asks for what several aircraft do not support.
    """

    several_aircraft = True
    slot_class = _TeamSlot

    def __init__(self, config: TrainConfig, run_dir: str | os.PathLike[str], **kwargs: Any) -> None:
        config = config.validate()
        self._check(config, kwargs.get("backend", "local"), kwargs.get("workers"))
        self.k = load_scene(config.scene, **config.scene_overrides).agents.count
        super().__init__(config, run_dir, **{**kwargs, "workers": 0})

    @staticmethod
    def _check(config: TrainConfig, backend: str, workers: int | None) -> None:
        if not is_multi_agent(config):
            raise ConfigError(f"scene {config.scene!r} has one aircraft: train it with Trainer")
        bad = _refused(config)
        if backend != "local" or workers:
            bad.append("--backend ray or --workers (the environments step in the learner's process)")
        if bad:
            raise ConfigError(f"scene {config.scene!r} has several aircraft; their shared training does not take "
                              f"{'; '.join(bad)}")

    # -- the environments ---------------------------------------------------------------------------------------
    def _make_envs(self, backend: str, ray_address: str | None) -> TeamEnvs:
        return TeamEnvs(self.config.num_envs, self.config, self.layout)

    def _noise_rows(self) -> int:
        return self.config.num_envs * self.k

    def start_episode(self, slot: _Slot, stage: int | None = None) -> None:
        slot.stage = self._stage_index()  # (no curriculum: the full scene)
        self._enter_episode(slot, self.envs.reset(slot.index, train_episode_seed(self.config.seed, slot.index,
                                                                                  slot.episode)))

    def _enter_episode(self, slot: _Slot, obs: np.ndarray) -> None:
        slot.obs = obs
        slot.actions, slot.ret, slot.length = [], 0.0, 0
        slot.live, slot.returns = np.ones(self.k, dtype=bool), np.zeros(self.k)
        for j in range(self.k):
            self.noise.reset(slot.index * self.k + j)

    # -- the loop -------------------------------------------------------------------------------------------------
    def collect(self, explore: bool = True) -> None:
        """One step of every environment, acted by the shared actor for every aircraft still taxiing; their
        transitions go into the buffer (and the learner's updates for them run first, from the buffer as it
        stood). ``explore=False`` (a DAgger round): the greedy actor acts and nothing but the buffer changes."""
        cfg, k = self.config, self.k
        rows = [(slot, j) for slot in self.slots for j in np.flatnonzero(slot.live)]
        obs = np.stack([slot.obs[j] for slot, j in rows])
        if explore and self.step < cfg.learning_starts and not self.buffer.n_demo:
            actions = self.rng.uniform(-1.0, 1.0, (len(rows), 2))
        else:
            actions = self.agent.acting()(obs)
            if explore:
                noise = self.noise.sample(self.rng)
                actions = actions + noise[[slot.index * k + j for slot, j in rows]]
            actions = np.clip(actions, -1.0, 1.0)
        joint = {slot.index: np.zeros((k, 2)) for slot in self.slots}
        for (slot, j), a in zip(rows, actions, strict=True):
            joint[slot.index][j] = a
        steps = {slot.index: self.envs.step(slot.index, joint[slot.index]) for slot in self.slots}
        if explore:
            self._learn(self.step + len(rows), len(rows))
        batch: dict[str, list[Any]] = {k_: [] for k_ in ("obs", "action", "reward", "next_obs", "terminated", "expert")}
        for (slot, j), a in zip(rows, actions, strict=True):
            next_obs, reward, agents, last, expert = steps[slot.index]
            batch["obs"].append(slot.obs[j])
            batch["action"].append(a)
            batch["reward"].append(reward[j])
            batch["next_obs"].append(next_obs[j])  # at a truncation: the final observation, bootstrapped through
            batch["terminated"].append(float(agents[j]["done"] or agents[j]["diverged"]))
            batch["expert"].append(None if expert is None else expert[j])
        for slot in self.slots:
            next_obs, reward, agents, last, _ = steps[slot.index]
            slot.actions.append(joint[slot.index])
            slot.length += 1
            self._account(slot, reward, agents, last)
            if last:
                slot.episode += 1
                self.start_episode(slot)
            else:
                slot.obs = next_obs
        arrays = {k_: np.asarray(v, dtype=np.float32) for k_, v in batch.items() if k_ != "expert"}
        if explore:
            self.agent.norm.update(arrays["obs"])
        expert = np.asarray(batch["expert"], dtype=np.float32) if cfg.expert_relabel else None
        self.buffer.add(arrays["obs"], arrays["action"], arrays["reward"], arrays["next_obs"], arrays["terminated"],
                        expert)
        self.collected = len(rows)
        self.step += len(rows)
        if explore:
            self._schedule()

    def _account(self, slot: _TeamSlot, reward: np.ndarray, agents: list[dict[str, Any]], last: bool,
                 stats: bool = True) -> None:
        """Add a step's rewards to the returns of ``slot``'s aircraft that were taxiing, and retire those that are
        done or (at the episode's end) timed out, counting their episodes in the statistics when ``stats``."""
        for j in np.flatnonzero(slot.live):
            slot.returns[j] += reward[j]
            slot.ret += float(reward[j])
            ended = agents[j]["done"] or agents[j]["diverged"]
            if ended or last:
                if stats:
                    self.stats.episode_end(outcome_of(agents[j], truncated=not ended), float(slot.returns[j]))
                slot.live[j] = False

    def _demonstrations(self) -> Demonstrations:
        """``demo_episodes`` episodes of the full-knowledge prioritised planner driving every aircraft (plus
        ``demo_noise``), each aircraft's transitions kept with the planner's action as its label."""
        cfg, k = self.config, self.k
        env = self.envs.make_env()
        teacher = self.envs.teacher(env)
        rng = np.random.default_rng([cfg.seed, 77])
        rows: dict[str, list[Any]] = {key: [] for key in ("obs", "action", "expert_action", "reward", "next_obs",
                                                          "terminated")}
        reached = 0
        bar = progress_report(range(cfg.demo_episodes), desc=f"demonstrations {cfg.scene}", unit="ep",
                              disable=not self.progress, leave=False)
        for episode in bar:
            env.random_state.seed(demo_episode_seed(cfg.seed, episode))
            ts = env.reset()
            teacher.reset()
            obs, live = self.envs.flatten(ts.observation), np.ones(k, dtype=bool)
            while not ts.last():
                expert = np.clip(teacher.act({}), -1.0, 1.0)
                noise = cfg.demo_noise * rng.standard_normal((k, 2)) if cfg.demo_noise > 0 else 0.0
                action = np.clip(expert + noise, -1.0, 1.0)
                ts = env.step(action)
                next_obs = self.envs.flatten(ts.observation)
                agents = env.task.last_info["agents"]
                for j in np.flatnonzero(live):
                    rows["obs"].append(obs[j])
                    rows["action"].append(action[j])
                    rows["expert_action"].append(expert[j])
                    rows["reward"].append(ts.reward[j])
                    rows["next_obs"].append(next_obs[j])
                    ended = agents[j]["done"] or env.task.last_info["diverged"]
                    rows["terminated"].append(float(ended))
                    live[j] = not ended
                obs = next_obs
            reached += sum(a["reached_goal"] for a in env.task.last_info["agents"])
            bar.set_postfix(reached=f"{100 * reached / ((episode + 1) * k):.0f}%")
        env.close()
        stack = {key: np.asarray(v, dtype=np.float32) for key, v in rows.items()}
        log.info("demonstrations: %d episodes, %d transitions, %d of %d aircraft reached", cfg.demo_episodes,
                 len(stack["obs"]), reached, cfg.demo_episodes * k)
        return Demonstrations(**stack, episodes=cfg.demo_episodes * k, successes=reached)

    # -- checkpoints --------------------------------------------------------------------------------------------
    def restore_slots(self, states: list[dict[str, Any]]) -> None:
        """Replay every environment's episode so far (its seed, its recorded joint actions, the planner asked at
        every step as it was), the aircraft's returns and which are done recomputed on the way."""
        for slot, saved in zip(self.slots, states, strict=True):
            slot.episode = int(saved["episode"])
            self.start_episode(slot)
            actions = saved["actions"].numpy().reshape(-1, self.k, 2)
            for joint in actions:
                next_obs, reward, agents, last, _ = self.envs.step(slot.index, joint)
                self._account(slot, reward, agents, last, stats=False)
                slot.obs = next_obs
                slot.actions.append(joint)
            if not np.array_equal(slot.obs, saved["obs"].numpy()):
                raise CheckpointError(
                    f"environment {slot.index} did not replay to its checkpointed state: the scene or deck_sim "
                    "changed since the checkpoint was written"
                )
            slot.ret, slot.length = float(saved["ret"]), int(saved["length"])

    # -- evaluation ---------------------------------------------------------------------------------------------
    def _held_out(self, episodes: int) -> dict[str, float]:
        """Held-out episodes of the shared greedy actor: ``summarize`` over every aircraft, with the team's
        ``all_reached_rate`` (also logged as ``eval/all_reached``)."""
        env = self._eval_environment()
        policy = SharedPolicy(self.actor_policy(), env)
        teams = [run_team_episode(env, policy, episode=e) for e in range(episodes)]
        summary = summarize([r for team in teams for r in team.aircraft])
        summary["episodes"] = float(episodes)
        summary["all_reached_rate"] = summarize_team(teams)["all_reached_rate"]
        self.runlog.scalar("eval/all_reached", summary["all_reached_rate"], self.step)
        return summary

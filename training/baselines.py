"""The paper's other baselines, DQN and A2C, through stable-baselines3 on the same Gymnasium adapter.

Both observe the current state only (predictor ``none``), as the paper's DQN and A2C do; observations are
normalised by SB3's ``VecNormalize`` (statistics frozen for evaluation). DQN acts on a discrete set of
displacements: stand still, or one of ``HEADINGS`` world-frame directions at each of ``SPEEDS`` fractions of the
reach (17 actions). A2C acts on the continuous (x, y) action like DDPG.

Every setting of a run is a field of its config (``DQNConfig`` or ``A2CConfig``, ``training.baseline_config``). A
run folder holds that config as ``config.json``, ``progress.csv`` and ``eval.csv`` with the columns of the DDPG
runs (where SB3 has them), TensorBoard logs under ``tb/``, and ``model.zip`` with ``vecnormalize.pkl`` (SB3's own
formats, which pickle: load only runs you trust) and ``clock.json`` (the step and wall-clock time at that save, from
which a resumed run's clock goes on). ``--resume`` loads them and goes on for the remaining steps with
the saved config (``resume_config``: only the budget and the evaluation and logging settings may change); unlike
the DDPG trainer it is not bit-exact (SB3 does not restore the environments' episodes).

As the DDPG trainer does, a run also writes its policy as a weights-only ``.npz`` that ``deck_sim.policies``
evaluates with numpy alone (``export_sb3``: format ``deck_sim.actor/2``): ``actor_best.npz`` at the best periodic
held-out evaluation so far and ``actor.npz`` at the end. DQN's file is its Q-network with an ``argmax`` head over
``discrete_actions()``, A2C's the mean of its Gaussian policy, clipped to [-1, 1] as SB3's deterministic
``predict`` does; both carry the ``VecNormalize`` observation statistics and give SB3's own actions.
"""

from __future__ import annotations

import contextlib
import csv
import json
import logging
import os
import signal
import threading
import time
from collections import deque
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np

import deck_sim
from deck_sim import agents
from deck_sim.metrics import outcome_of, summarize
from deck_sim.policies import ACTOR_FORMAT_V2, LearnedPolicy, write_actor_file
from deck_sim.progress import progress as progress_report
from deck_sim.rollout import git_commit, run_episode
from deck_sim.wrappers import DeckSimEnv
from training.baseline_config import A2CConfig, BaselineConfig, DQNConfig, baseline_config
from training.config import ConfigError, train_episode_seed
from training.runlog import EVAL_FIELDS, PROGRESS_FIELDS, eval_row

log = logging.getLogger(__name__)

HEADINGS = 8
SPEEDS = (0.5, 1.0)
BASELINES = tuple(a for a in agents.ALGOS if agents.AGENTS[a].trainer == "sb3")
"""The stable-baselines3 algorithms (``dqn``, ``a2c``)."""
RESUMABLE_BASELINE_CHANGES = ("total_steps", "eval_every", "eval_episodes", "log_every")
"""Config fields a resumed DQN or A2C run may change: a longer run, and how often and on how many episodes it is
evaluated and logged."""


def discrete_actions() -> np.ndarray:
    """The DQN action table (1 + HEADINGS * len(SPEEDS), 2): displacement requests in [-1, 1]^2."""
    rows = [np.zeros(2)]
    for s in SPEEDS:
        for k in range(HEADINGS):
            angle = 2.0 * np.pi * k / HEADINGS
            rows.append(s * np.array([np.cos(angle), np.sin(angle)]))
    return np.array(rows)


class DiscreteDisplacement(gymnasium.ActionWrapper):
    """Discrete actions for DQN: index -> a row of ``discrete_actions()``."""

    def __init__(self, env: gymnasium.Env) -> None:
        super().__init__(env)
        self.table = discrete_actions()
        self.action_space = gymnasium.spaces.Discrete(len(self.table))

    def action(self, action: Any) -> np.ndarray:
        return self.table[int(action)].astype(np.float32)


class SeededEpisodes(gymnasium.Wrapper):
    """Resets episode ``k`` with ``train_episode_seed(seed, stream, k)`` (disjoint from evaluation seeds; one stream
    per environment of a run)."""

    def __init__(self, env: gymnasium.Env, seed: int, stream: int = 0) -> None:
        super().__init__(env)
        self.run_seed, self.stream, self.episode = seed, stream, 0

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        out = self.env.reset(seed=train_episode_seed(self.run_seed, self.stream, self.episode), options=options)
        self.episode += 1
        return out


def _make_env(algo: str, scene: str, seed: int, overrides: dict[str, Any], stream: int = 0) -> gymnasium.Env:
    env: gymnasium.Env = SeededEpisodes(DeckSimEnv(scene, episode__predictor="none", **overrides), seed, stream)
    return DiscreteDisplacement(env) if algo == "dqn" else env


def _env_maker(algo: str, scene: str, seed: int, overrides: dict[str, Any], stream: int) -> Any:
    return lambda: _make_env(algo, scene, seed, overrides, stream)


class SB3Policy:
    """A trained SB3 model with the ``act(observation_dict)`` interface of deck_sim's policies."""

    def __init__(self, model: Any, vecnormalize: Any, keys: tuple[str, ...], discrete: bool) -> None:
        self.model, self.vecnormalize, self.keys, self.discrete = model, vecnormalize, keys, discrete
        self.table = discrete_actions()

    def reset(self) -> None:
        """SB3's MLP policies have no memory."""

    def act(self, observation: dict[str, np.ndarray]) -> np.ndarray:
        x = np.concatenate([np.ravel(observation[k]) for k in self.keys]).astype(np.float32)[None]
        x = self.vecnormalize.normalize_obs(x)
        action, _ = self.model.predict(x, deterministic=True)
        if self.discrete:
            return self.table[int(np.ravel(action)[0])]
        return np.clip(np.ravel(action), -1.0, 1.0)


def _mlp_layers(modules: list[Any]) -> tuple[list[tuple[np.ndarray, np.ndarray]], str]:
    """The (weight, bias) pairs of an alternating Linear / activation / ... / Linear stack, and the activation."""
    import torch

    layers, acts = [], set()
    for i, m in enumerate(modules):
        expect_linear = i % 2 == 0
        if expect_linear and isinstance(m, torch.nn.Linear):
            layers.append((m.weight.detach().cpu().double().numpy(), m.bias.detach().cpu().double().numpy()))
        elif not expect_linear and isinstance(m, (torch.nn.ReLU, torch.nn.Tanh)):
            acts.add("relu" if isinstance(m, torch.nn.ReLU) else "tanh")
        else:
            raise ValueError(f"cannot export layer {i} ({type(m).__name__}): expected Linear layers and ReLU or Tanh")
    if len(modules) % 2 != 1 or len(acts) > 1:
        raise ValueError("cannot export the network: not a Linear stack with one hidden activation")
    return layers, acts.pop() if acts else "relu"


def export_sb3(
    model: Any, vecnormalize: Any, algo: str, meta: dict[str, Any]
) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """A DQN or A2C model (``MlpPolicy``) and its ``VecNormalize`` as the arrays and ``meta`` of a weights-only
    ``deck_sim.actor/2`` file (``LearnedPolicy``); ``meta`` must give the observation keys and shapes."""
    from stable_baselines3.common.torch_layers import FlattenExtractor

    if algo == "dqn":
        net = model.q_net
        modules = list(net.q_net)
        head = "argmax"
    elif algo == "a2c":
        net = model.policy
        if not net.share_features_extractor and not isinstance(net.pi_features_extractor, FlattenExtractor):
            raise ValueError("cannot export an A2C policy with its own features extractor")
        modules = [*net.mlp_extractor.policy_net, net.action_net]
        head = "clip"
    else:
        raise ValueError(f"unknown baseline {algo!r}; expected one of {', '.join(BASELINES)}")
    if not isinstance(net.features_extractor, FlattenExtractor):
        raise ValueError(f"cannot export a {type(net.features_extractor).__name__}: only flat observations")
    layers, activation = _mlp_layers(modules)
    arrays: dict[str, np.ndarray] = {}
    for i, (w, b) in enumerate(layers):
        arrays[f"w{i}"], arrays[f"b{i}"] = w.astype(np.float32), b.astype(np.float32)
    rms = vecnormalize.obs_rms
    arrays["norm_enabled"] = np.array(bool(vecnormalize.norm_obs))
    arrays["norm_mean"] = np.asarray(rms.mean, dtype=np.float64)
    arrays["norm_std"] = np.sqrt(np.asarray(rms.var, dtype=np.float64) + vecnormalize.epsilon)
    arrays["norm_clip"] = np.array(float(vecnormalize.clip_obs))
    if algo == "dqn":
        arrays["action_table"] = discrete_actions()
    full = {
        **meta,
        "format": ACTOR_FORMAT_V2,
        "algo": algo,
        "regime": "reward",  # stable-baselines3 learns from the environment's reward alone
        "activation": activation,
        "head": head,
        # the Gymnasium adapter hands SB3 float32 observations; the numpy policy rounds its input the same way
        "input_dtype": "float32",
        "predictor": "none",
    }
    return arrays, full


def save_sb3_actor(path: str | os.PathLike[str], model: Any, vecnormalize: Any, algo: str, meta: dict) -> None:
    """Write ``export_sb3``'s file atomically (float32 weights: a few hundred KiB)."""
    arrays, full = export_sb3(model, vecnormalize, algo, meta)
    LearnedPolicy(arrays, full, source=str(path))  # refuse to write a file deck_sim cannot read
    write_actor_file(path, arrays, full)


def saved_baseline_config(run_dir: str | os.PathLike[str]) -> BaselineConfig:
    """The config of the DQN or A2C run in ``run_dir`` as its ``config.json`` records it; a ``config.json`` that names
    the run's length ``steps`` and holds the SB3 keywords under ``sb3`` (and the predictor, always ``none``) is read
    as well. ``CheckpointError`` naming the file if it is missing or holds no such config."""
    from training.checkpoints import CheckpointError

    path = Path(run_dir) / "config.json"
    try:
        saved = json.loads(path.read_text())
    except FileNotFoundError:
        raise CheckpointError(f"{run_dir}: no DQN or A2C run to resume (no config.json)") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise CheckpointError(f"{path}: not a readable run config ({err})") from err
    if not isinstance(saved, dict) or not isinstance(saved.get("sb3", {}), dict):
        raise CheckpointError(f"{path}: not a DQN or A2C run config (expected a JSON object of its fields)")
    fields = {k: v for k, v in saved.items() if k not in ("algo", "steps", "sb3", "predictor")}
    fields.update(saved.get("sb3", {}))
    if "total_steps" not in fields and "steps" in saved:
        fields["total_steps"] = saved["steps"]
    try:
        return baseline_config(saved.get("algo"), **fields)
    except ConfigError as err:
        raise CheckpointError(f"{path}: not a DQN or A2C run config: {err}") from err


def resume_config(algo: str, run_dir: str | os.PathLike[str], **fields: Any) -> BaselineConfig:
    """The config a resumed run in ``run_dir`` trains with: its saved one (``saved_baseline_config``) with ``fields``
    applied. A field outside ``RESUMABLE_BASELINE_CHANGES`` may only repeat the saved value, and ``algo`` must be the
    run's: ``ConfigError`` naming each one given otherwise and the run's value."""
    saved = saved_baseline_config(run_dir)
    if algo != saved.algo:
        raise ConfigError(f"algo: the run in {run_dir} is a {saved.algo} run, not {algo}")
    mine = saved.to_dict()
    wanted = baseline_config(saved.algo, **{k: v for k, v in {**mine, **fields}.items() if k != "algo"}).to_dict()
    fixed = [k for k in sorted(fields) if k not in RESUMABLE_BASELINE_CHANGES and wanted[k] != mine[k]]
    if fixed:
        detail = "; ".join(f"{k}: the run's {mine[k]!r}, given {wanted[k]!r}" for k in fixed)
        raise ConfigError(
            f"{run_dir}: a resumed run keeps its config but for {', '.join(RESUMABLE_BASELINE_CHANGES)} ({detail})"
        )
    return type(saved).from_dict(wanted)


def train_baseline(
    algo: str,
    scene: str,
    steps: int | None,
    seed: int,
    out: str | Path,
    resume: bool = False,
    progress: bool = True,
    **overrides: Any,
) -> dict[str, Any]:
    """Train SB3's DQN or A2C on ``scene`` for ``steps`` environment steps in ``out`` (None: the config's default,
    or a resumed run's own).

    ``overrides`` are fields of the algorithm's config (``DQNConfig`` or ``A2CConfig``: SB3 hyperparameters such
    as ``learning_rate``, the evaluation and logging settings, ``scene_overrides``); the config is checked before
    anything is built (``ConfigError`` naming an unknown field or a bad value) and saved as ``config.json`` with a
    new run. A resumed run keeps its saved config (``resume_config``: ``algo``, ``scene``, ``seed`` and any other
    field given must repeat the saved value, but for ``RESUMABLE_BASELINE_CHANGES``) and continues the saved model
    to ``steps``, which may not be below the steps it has done (``CheckpointError`` naming both, before anything is
    written). Returns the last held-out evaluation and the run's counters, in the shape ``Trainer.train`` returns.
    Writes ``actor_best.npz`` (best periodic evaluation) and ``actor.npz`` (final) for
    ``deck_sim.policies.LearnedPolicy``. Ctrl-C stops the run after its current step with the model and its
    normalisation saved (each file written whole, then renamed), and DQN's replay buffer (``replay_buffer.pkl``),
    and no actor exported; the summary's ``stopped`` is then true and ``resume`` goes on from that step with the
    networks, optimiser, normaliser, schedules and replay buffer as saved (every periodic evaluation saves them
    too). The resumed run's environments start new episodes, so it does not repeat an unbroken run step for step
    as a resumed DDPG run does.
    """
    if "total_steps" in overrides:
        raise ConfigError("total_steps: given by the steps argument (deck-sim train --steps)")
    fields = {"scene": scene, "seed": seed, **overrides}
    if steps is not None:
        fields["total_steps"] = int(steps)
    cfg = resume_config(algo, out, **fields) if resume else baseline_config(algo, **fields)

    from stable_baselines3 import A2C, DQN
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    from training.checkpoints import CheckpointError

    scene, seed, steps, overrides = cfg.scene, cfg.seed, cfg.total_steps, cfg.scene_overrides
    eval_every, eval_episodes, eval_seed, log_every = cfg.eval_every, cfg.eval_episodes, cfg.eval_seed, cfg.log_every
    out = Path(out)
    venv = DummyVecEnv([_env_maker(algo, scene, seed, overrides, i) for i in range(cfg.num_envs)])
    keys = venv.envs[0].unwrapped.observation_keys
    shapes = venv.envs[0].unwrapped.composer_env.task.observation_shapes
    model_path, norm_path, buffer_path = out / "model.zip", out / "vecnormalize.pkl", out / "replay_buffer.pkl"
    cls = DQN if algo == "dqn" else A2C
    done_steps = 0
    if resume:
        if not model_path.exists() or not norm_path.exists():
            raise CheckpointError(f"{out}: no model.zip and vecnormalize.pkl to resume from")
        # SB3 raises many types for a damaged zip or pickle; the message keeps their first line
        try:
            venv = VecNormalize.load(str(norm_path), venv)
        except Exception as err:
            raise CheckpointError(f"{norm_path}: not a readable VecNormalize file ({_first_line(err)})") from err
        try:
            model = cls.load(str(model_path), env=venv)
        except Exception as err:
            raise CheckpointError(f"{model_path}: not a readable {algo} model ({_first_line(err)})") from err
        done_steps = int(model.num_timesteps)
        if algo == "dqn":
            if buffer_path.exists():
                try:
                    model.load_replay_buffer(str(buffer_path))
                except Exception as err:
                    raise CheckpointError(
                        f"{buffer_path}: not a readable replay buffer ({_first_line(err)})"
                    ) from err
            else:
                log.warning("%s: no replay buffer saved with the model; the resumed run starts with an empty one", out)
        if steps < done_steps:
            raise CheckpointError(
                f"{out}: the run has done {done_steps} steps; a budget of {steps} steps (total_steps, --steps) is "
                "below that"
            )
        earlier = _read_rows(out / "eval.csv")
        wall_before = wall_at_save(out, done_steps, earlier)  # eval.csv's clock spans every process
        best_success = max((float(r["success"]) for r in earlier), default=-1.0)
        with open(out / "eval.csv", "w", newline="") as f:  # rewritten with EVAL_FIELDS, whatever columns it had
            w = csv.DictWriter(f, fieldnames=EVAL_FIELDS, restval="")
            w.writeheader()
            w.writerows({k: r.get(k, "") for k in EVAL_FIELDS} for r in earlier)
    else:
        wall_before, best_success = 0.0, -1.0
        if model_path.exists():
            raise CheckpointError(f"{out} already holds a run (model.zip); resume it with --resume or choose another")
        out.mkdir(parents=True, exist_ok=True)
        venv = VecNormalize(venv, norm_obs=True, norm_reward=False, clip_obs=10.0)
        model = cls(
            "MlpPolicy",
            venv,
            seed=seed,
            verbose=0,
            tensorboard_log=str(out / "tb"),
            policy_kwargs={"net_arch": list(cfg.net_arch)},
            **cfg.sb3_kwargs(),
        )
        for name, columns in (("progress.csv", PROGRESS_FIELDS), ("eval.csv", EVAL_FIELDS)):
            with open(out / name, "w", newline="") as f:
                csv.DictWriter(f, fieldnames=columns).writeheader()
        cfg.save(out / "config.json")
    eval_env = deck_sim.load(scene, seed=eval_seed, **{**overrides, "episode__predictor": "none"})
    run_config = json.loads((out / "config.json").read_text())
    best = {"success": best_success}

    def actor_meta(step: int) -> dict[str, Any]:
        return {
            "scene": scene,
            "scene_overrides": overrides,
            "observation_keys": list(keys),
            "observation_shapes": {k: list(v) for k, v in shapes.items()},
            "trained_steps": int(step),
            # (a config.json that names the run's length ``steps`` rather than ``total_steps`` is read as well)
            "config": {**run_config, "total_steps": int(run_config.get("total_steps", run_config.get("steps")))},
            "deck_sim_version": deck_sim.__version__,
            "git_commit": git_commit(),
        }

    def evaluate(step: int, wall: float) -> dict[str, float]:
        venv.training = False
        eval_env.random_state.seed(eval_seed)
        policy = SB3Policy(model, venv, keys, algo == "dqn")
        summary = summarize([run_episode(eval_env, policy, k) for k in range(eval_episodes)])
        if summary["goal_rate"] > best["success"]:  # as the DDPG trainer picks actor_best.npz
            best["success"] = summary["goal_rate"]
            save_sb3_actor(out / "actor_best.npz", model, venv, algo, actor_meta(step))
        venv.training = True
        with open(out / "eval.csv", "a", newline="") as f:
            csv.DictWriter(f, fieldnames=EVAL_FIELDS).writerow(eval_row(step, wall_before + wall, summary))
        return summary

    class Logger(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.recent: deque[tuple[str, float]] = deque(maxlen=50)
            self.ret = np.zeros(cfg.num_envs)
            self.t0 = time.perf_counter()
            self.t_log, self.n_log = self.t0, done_steps
            self.bar = progress_report(
                total=steps, initial=done_steps, desc=f"{algo} {scene}", unit="step", disable=not progress
            )
            self.last_eval: dict[str, float] = {}
            self.last_eval_step = -1
            self.episodes = 0
            # log and evaluate when the step count reaches a multiple of the period (with several environments
            # it moves in strides of their number)
            self.log_block = done_steps // log_every
            self.eval_block = done_steps // eval_every if eval_every else 0

        def _on_step(self) -> bool:
            self.ret += np.asarray(self.locals["rewards"], dtype=np.float64)
            for i, done in enumerate(self.locals["dones"]):
                if not done:
                    continue
                info = self.locals["infos"][i]
                truncated = bool(info.get("TimeLimit.truncated", False)) or (
                    not info["reached_goal"]
                    and not info["collision"]
                    and not info["left_surface"]
                    and not info["diverged"]
                )
                self.recent.append((outcome_of(info, truncated), float(self.ret[i])))
                self.ret[i] = 0.0
                self.episodes += 1
            n = self.num_timesteps
            self.bar.update(n - self.bar.n)
            if n // log_every > self.log_block:
                self.log_block = n // log_every
                now = time.perf_counter()
                outcomes = [o for o, _ in self.recent]
                k = max(len(outcomes), 1)
                row = {
                    "step": n,
                    "episodes": self.episodes,  # all episodes so far, as the DDPG trainer counts them
                    "wall_s": round(now - self.t0, 2),
                    "sps": round((n - self.n_log) / max(now - self.t_log, 1e-9), 1),
                    "ep_reward": float(np.mean([r for _, r in self.recent])) if self.recent else 0.0,
                    "success": outcomes.count("goal") / k,
                    "collision": outcomes.count("collision") / k,
                    "timeout": outcomes.count("timeout") / k,
                    "critic_loss": self.logger.name_to_value.get(
                        "train/loss", self.logger.name_to_value.get("train/value_loss", "")
                    ),
                    "actor_loss": self.logger.name_to_value.get("train/policy_loss", ""),
                }
                self.t_log, self.n_log = now, n
                with open(out / "progress.csv", "a", newline="") as f:
                    csv.DictWriter(f, fieldnames=PROGRESS_FIELDS).writerow(
                        {k2: row.get(k2, "") for k2 in PROGRESS_FIELDS}
                    )
                self.bar.set_postfix(success=f"{row['success']:.0%}", reward=f"{row['ep_reward']:.0f}")
            if eval_every and n // eval_every > self.eval_block:
                self.eval_block = n // eval_every
                self.last_eval, self.last_eval_step = evaluate(n, time.perf_counter() - self.t0), n
                save()
            return not stop["requested"]

    def save() -> None:  # each file written whole under another name, then renamed over the last
        tmp_model, tmp_norm = out / "model.tmp.zip", out / "vecnormalize.tmp.pkl"
        model.save(str(tmp_model))
        venv.save(str(tmp_norm))
        if algo == "dqn":  # (DQN's replay buffer, so that a resumed run learns from what it had gathered)
            tmp_buffer = out / "replay_buffer.tmp.pkl"
            model.save_replay_buffer(str(tmp_buffer))
            os.replace(tmp_buffer, buffer_path)
        os.replace(tmp_model, model_path)
        os.replace(tmp_norm, norm_path)
        clock = {"step": int(model.num_timesteps), "wall_s": wall_before + time.perf_counter() - logger.t0}
        tmp_clock = out / "clock.tmp.json"
        tmp_clock.write_text(json.dumps(clock), encoding="utf-8")
        os.replace(tmp_clock, out / CLOCK_FILE)

    logger = Logger()
    t0 = time.perf_counter()
    remaining = max(0, steps - done_steps)
    stop = {"requested": False}
    with _stop_on_sigint(stop):
        model.learn(total_timesteps=remaining, callback=logger, reset_num_timesteps=not resume, tb_log_name=algo)
        logger.bar.close()
        save()
    if stop["requested"] and model.num_timesteps < steps:
        log.warning("stopped at step %d of %d; --resume goes on from there", model.num_timesteps, steps)
        return {
            "step": int(model.num_timesteps),
            "wall_s": time.perf_counter() - t0,
            "episodes": logger.episodes,
            "eval": logger.last_eval,
            "stopped": True,
        }
    last = logger.last_eval if logger.last_eval_step == model.num_timesteps else {}
    if not last:
        last = evaluate(int(model.num_timesteps), time.perf_counter() - t0)
    save_sb3_actor(out / "actor.npz", model, venv, algo, actor_meta(int(model.num_timesteps)))
    return {
        "step": int(model.num_timesteps),
        "wall_s": time.perf_counter() - t0,
        "episodes": logger.episodes,
        "eval": last,
        "stopped": False,
    }


@contextlib.contextmanager
def _stop_on_sigint(stop: dict[str, bool]) -> Iterator[None]:
    """Inside: Ctrl-C sets ``stop["requested"]`` (the run stops after its current step and saves its model), in
    the main thread; the previous handler is back afterwards."""

    def on_sigint(signum: int, frame: Any) -> None:  # noqa: ARG001
        log.warning("interrupted: stopping after this step with the model saved (resume with --resume)")
        stop["requested"] = True

    main_thread = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGINT, on_sigint) if main_thread else None
    try:
        yield
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)


def _first_line(err: BaseException) -> str:
    """An exception's message in one line (its first), or its type's name if it has none."""
    text = str(err).strip()
    return text.splitlines()[0] if text else type(err).__name__


CLOCK_FILE = "clock.json"
"""Beside a DQN or A2C run's saved model: ``{"step", "wall_s"}``, the run's step count and its wall-clock seconds
summed over every process when the model was last saved, so that a resumed run's clock counts the time between its
last evaluation and the stop."""


def wall_at_save(run: Path, step: int, rows: list[dict[str, str]]) -> float:
    """The wall-clock seconds a run had trained when its model, now at ``step``, was saved: ``CLOCK_FILE`` if it
    was written at that step, else the last evaluation row's (``rows``: ``eval.csv``; a run saved before the clock
    was kept), else 0."""
    try:
        clock = json.loads((run / CLOCK_FILE).read_text(encoding="utf-8"))
        if int(clock["step"]) == step:
            return float(clock["wall_s"])
    except (OSError, ValueError, KeyError, TypeError):
        pass
    return float(rows[-1]["wall_s"]) if rows else 0.0


def _read_rows(path: Path) -> list[dict[str, str]]:
    if not path.exists():
        return []
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def load_baseline(run_dir: str | Path) -> SB3Policy:
    """The SB3 policy of a DQN or A2C run folder (``model.zip`` and ``vecnormalize.pkl``)."""
    from stable_baselines3 import A2C, DQN
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    run_dir = Path(run_dir)
    cfg = json.loads((run_dir / "config.json").read_text())
    algo = cfg["algo"]
    venv = DummyVecEnv([_env_maker(algo, cfg["scene"], cfg["seed"], cfg.get("scene_overrides", {}), 0)])
    keys = venv.envs[0].unwrapped.observation_keys
    norm = VecNormalize.load(str(run_dir / "vecnormalize.pkl"), venv)
    norm.training = False
    model = (DQN if algo == "dqn" else A2C).load(str(run_dir / "model.zip"))
    return SB3Policy(model, norm, keys, algo == "dqn")


__all__ = [
    "BASELINES",
    "RESUMABLE_BASELINE_CHANGES",
    "A2CConfig",
    "BaselineConfig",
    "DQNConfig",
    "SB3Policy",
    "discrete_actions",
    "baseline_config",
    "export_sb3",
    "load_baseline",
    "resume_config",
    "save_sb3_actor",
    "saved_baseline_config",
    "train_baseline",
]

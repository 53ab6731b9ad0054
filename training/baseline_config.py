"""Every setting of a DQN or A2C baseline run (``training.baselines``) in one dataclass per algorithm, a docstring
per field, as ``TrainConfig`` is for DDPG / MDDPG.

The run writes its config as ``config.json`` beside its logs. The stable-baselines3 hyperparameters are passed to
SB3's constructor explicitly (``sb3_kwargs``), so a run does not depend on the defaults of the installed SB3;
where a default here differs from SB3's, the field says so. ``baseline_config`` builds and checks one from the
fields a caller gives (``deck-sim train --algo dqn --set field=value``): an unknown field, a value of the wrong type
or out of range raises ``training.config.ConfigError`` naming the field.
"""

from __future__ import annotations

import dataclasses
import json
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

from training.config import ConfigError, field_value


@dataclass
class BaselineConfig:
    """The settings DQN and A2C share: the scene, the run's length, the network, the evaluations and the logs."""

    algo: ClassVar[str] = ""
    """``dqn`` or ``a2c`` (fixed by the subclass)."""
    SB3_FIELDS: ClassVar[tuple[str, ...]] = ()
    """The fields passed to the SB3 constructor as keywords of the same name."""
    _at_least_one: ClassVar[tuple[str, ...]] = ()
    _non_negative: ClassVar[tuple[str, ...]] = ()
    _fractions: ClassVar[tuple[str, ...]] = ()
    _positive: ClassVar[tuple[str, ...]] = ()
    """The subclass's fields checked by ``validate`` for each range (besides the shared fields)."""

    scene: str = "deck1"
    """Scene name or TOML path."""
    scene_overrides: dict[str, Any] = field(default_factory=dict)
    """Scene fields as ``<section>__<field>`` (``deck_sim.load``'s overrides), for training and evaluation alike
    (the predictor is always ``none``: the baselines observe the current state only)."""
    seed: int = 0
    """Seeds SB3 (networks, exploration, replay sampling) and the training episodes
    (``train_episode_seed(seed, 0, k)``)."""
    total_steps: int = 50_000
    """Environment steps (decisions) to train for."""
    gamma: float = 0.99
    """Discount factor."""
    net_arch: tuple[int, ...] = (256, 256)
    """Hidden layer widths of SB3's ``MlpPolicy`` (``policy_kwargs["net_arch"]``; A2C: of the actor and of the
    critic each). SB3's default is (64, 64)."""

    num_envs: int = 1
    """Environments stepped in lockstep (SB3's ``DummyVecEnv``); environment ``i`` plays the training episodes
    ``train_episode_seed(seed, i, k)``. A2C's rollout is ``n_steps`` steps of each. 1: one environment."""

    eval_every: int = 10_000
    """Evaluate the greedy policy every this many environment steps, and save ``model.zip`` (0: only at the
    end)."""
    eval_episodes: int = 20
    """Episodes per evaluation."""
    eval_seed: int = 500
    """Seed of the evaluation environment (consecutive episodes; held out: below ``TRAIN_SEED_BASE``)."""
    log_every: int = 1_000
    """Write a ``progress.csv`` row of training statistics every this many environment steps."""

    def sb3_kwargs(self) -> dict[str, Any]:
        """The SB3 constructor's hyperparameter keywords (``SB3_FIELDS``)."""
        return {name: getattr(self, name) for name in self.SB3_FIELDS}

    def validate(self) -> BaselineConfig:
        """Raise ``ConfigError`` naming the first field of the wrong type or with an impossible value; return self.
        An integer is taken where a float is expected (and stored as a float)."""
        hints = typing.get_type_hints(type(self))
        for f in dataclasses.fields(self):
            setattr(self, f.name, field_value(f.name, getattr(self, f.name), hints[f.name]))
        if self.num_envs > 9:  # training.config.train_episode_seed's streams
            raise ConfigError(f"num_envs: at most 9, got {self.num_envs!r}")
        if not 0 <= self.seed < 4_000:
            raise ConfigError(f"seed: must lie in [0, 4000) (episode seeds must fit in 32 bits), got {self.seed!r}")
        for name in ("total_steps", "num_envs", "eval_episodes", "log_every", *self._at_least_one):
            if getattr(self, name) < 1:
                raise ConfigError(f"{name}: must be at least 1, got {getattr(self, name)!r}")
        for name in ("eval_every", *self._non_negative):
            if getattr(self, name) < 0:
                raise ConfigError(f"{name}: must be >= 0, got {getattr(self, name)!r}")
        for name in ("gamma", *self._fractions):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ConfigError(f"{name}: must lie in [0, 1], got {getattr(self, name)!r}")
        for name in self._positive:
            if not getattr(self, name) > 0.0:
                raise ConfigError(f"{name}: must be positive, got {getattr(self, name)!r}")
        if not self.net_arch or any(h < 1 for h in self.net_arch):
            raise ConfigError(f"net_arch: expected positive layer widths, got {self.net_arch!r}")
        return self

    def to_dict(self) -> dict[str, Any]:
        """A JSON-serialisable copy, ``algo`` included."""
        d = dataclasses.asdict(self)
        d["net_arch"] = list(self.net_arch)
        return {"algo": self.algo, **d}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> BaselineConfig:
        """A validated config from ``d`` (``to_dict``'s form; ``algo``, if given, must be this class's);
        unknown fields raise ``ConfigError``."""
        d = dict(d)
        algo = d.pop("algo", cls.algo)
        if algo != cls.algo:
            raise ConfigError(f"algo: this is a {cls.algo} config, got {algo!r}")
        regime = d.pop("regime", "reward")
        if regime != "reward":
            raise ConfigError(f"regime: {cls.algo} learns from the reward alone, the config says {regime!r}")
        names = [f.name for f in dataclasses.fields(cls)]
        unknown = sorted(set(d) - set(names))
        if unknown:
            raise ConfigError(
                f"unknown {cls.algo} config field(s): {', '.join(unknown)} (the fields: {', '.join(names)})"
            )
        return cls(**d).validate()

    def save(self, path: str | Path) -> None:
        """Write the config as JSON, with its regime (``reward``: stable-baselines3 learns from the reward alone)."""
        Path(path).write_text(json.dumps({**self.to_dict(), "regime": "reward"}, indent=2, sort_keys=True) + "\n")


@dataclass
class DQNConfig(BaselineConfig):
    """A DQN run: SB3's ``DQN`` on the 17 discrete displacements of ``training.baselines.discrete_actions``."""

    algo: ClassVar[str] = "dqn"
    SB3_FIELDS: ClassVar[tuple[str, ...]] = (
        "learning_rate",
        "buffer_size",
        "learning_starts",
        "batch_size",
        "tau",
        "gamma",
        "train_freq",
        "gradient_steps",
        "target_update_interval",
        "exploration_fraction",
        "exploration_initial_eps",
        "exploration_final_eps",
        "max_grad_norm",
    )
    _at_least_one: ClassVar[tuple[str, ...]] = (
        "buffer_size",
        "batch_size",
        "train_freq",
        "gradient_steps",
        "target_update_interval",
    )
    _non_negative: ClassVar[tuple[str, ...]] = ("learning_starts",)
    _fractions: ClassVar[tuple[str, ...]] = (
        "tau",
        "exploration_fraction",
        "exploration_initial_eps",
        "exploration_final_eps",
    )
    _positive: ClassVar[tuple[str, ...]] = ("learning_rate", "max_grad_norm")

    learning_rate: float = 1e-4
    """Adam learning rate of the Q-network."""
    buffer_size: int = 300_000
    """Replay capacity in transitions (SB3's default: 1,000,000)."""
    learning_starts: int = 2_000
    """Environment steps of exploration before the first update (SB3's default: 100)."""
    batch_size: int = 32
    """Transitions per update."""
    tau: float = 1.0
    """Target network update rate (1: the target is copied every ``target_update_interval`` steps)."""
    train_freq: int = 4
    """Update the Q-network every this many environment steps."""
    gradient_steps: int = 1
    """Gradient steps per update."""
    target_update_interval: int = 2_000
    """Environment steps between target network updates (SB3's default: 10,000)."""
    exploration_fraction: float = 0.3
    """Fraction of ``total_steps`` over which epsilon falls from ``exploration_initial_eps`` to
    ``exploration_final_eps`` (SB3's default: 0.1)."""
    exploration_initial_eps: float = 1.0
    """Probability of a random action at the start of training."""
    exploration_final_eps: float = 0.05
    """Probability of a random action once the exploration schedule is over."""
    max_grad_norm: float = 10.0
    """Clip the gradient norm of each update to this value."""


@dataclass
class A2CConfig(BaselineConfig):
    """An A2C run: SB3's ``A2C`` with a Gaussian policy on the continuous (x, y) action, as DDPG acts."""

    algo: ClassVar[str] = "a2c"
    SB3_FIELDS: ClassVar[tuple[str, ...]] = (
        "learning_rate",
        "n_steps",
        "gamma",
        "gae_lambda",
        "ent_coef",
        "vf_coef",
        "max_grad_norm",
        "rms_prop_eps",
        "use_rms_prop",
        "normalize_advantage",
    )
    _at_least_one: ClassVar[tuple[str, ...]] = ("n_steps",)
    _non_negative: ClassVar[tuple[str, ...]] = ("ent_coef", "vf_coef")
    _fractions: ClassVar[tuple[str, ...]] = ("gae_lambda",)
    _positive: ClassVar[tuple[str, ...]] = ("learning_rate", "max_grad_norm", "rms_prop_eps")

    learning_rate: float = 7e-4
    """Learning rate of the policy and value networks."""
    n_steps: int = 16
    """Environment steps per update (the rollout's length; SB3's default: 5)."""
    gae_lambda: float = 1.0
    """Generalised advantage estimation's lambda (1: the plain discounted advantage)."""
    ent_coef: float = 0.0
    """Weight of the entropy bonus in the loss."""
    vf_coef: float = 0.5
    """Weight of the value loss in the loss."""
    max_grad_norm: float = 0.5
    """Clip the gradient norm of each update to this value."""
    rms_prop_eps: float = 1e-5
    """Epsilon of the RMSprop optimiser."""
    use_rms_prop: bool = True
    """Optimise with RMSprop (off: Adam)."""
    normalize_advantage: bool = False
    """Normalise the advantages of each rollout to zero mean and unit variance."""


BASELINE_CONFIGS: dict[str, type[BaselineConfig]] = {"dqn": DQNConfig, "a2c": A2CConfig}
"""The config class of each baseline algorithm."""


def baseline_config(algo: str, **fields: Any) -> BaselineConfig:
    """A validated ``DQNConfig`` or ``A2CConfig`` of ``fields`` (the others at their defaults)."""
    if algo not in BASELINE_CONFIGS:
        raise ConfigError(f"algo: expected one of {', '.join(BASELINE_CONFIGS)}, got {algo!r}")
    return BASELINE_CONFIGS[algo].from_dict(fields)

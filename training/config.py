"""Every hyperparameter of a DDPG / MDDPG run in one dataclass, a docstring per field (cleanrl's ``Args``).

The run writes its ``TrainConfig`` out as ``config.json`` beside its logs and checkpoints. Two presets name the
recipes compared in ``benchmarks/learning.py``: ``paper`` (plain DDPG as the paper describes it: one environment,
one update per step, Gaussian noise, no demonstrations, no normalisation) and ``tuned`` (the switches
measured to pay on the physical deck; ``docs/training.md``, "Switches and their measured effects").

Seeds: training episode ``k`` of environment ``i`` in a run seeded ``s`` is reset with
``train_episode_seed(s, i, k)``, demonstration episode ``k`` with ``demo_episode_seed(s, k)``; both lie at or above
``TRAIN_SEED_BASE`` (10^6). Evaluation plays consecutive episodes of one environment seeded below it
(``eval_seed``, default 500; the shipped agents' held-out figures use ``deck-sim run --seed 1000``), so no evaluation
episode is a training episode.
"""

from __future__ import annotations

import dataclasses
import json
import math
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from deck_sim import agents
from deck_sim.control.prediction import PREDICTOR_NAMES
from deck_sim.evaluation import TRAIN_SEED_BASE
from deck_sim.policies.regimes import TEACHING_FIELDS, config_regime
from training.noise import HOLD_ACTIONS

ALGOS = tuple(a for a in agents.ALGOS if agents.AGENTS[a].trainer == "ddpg")
"""The training algorithms of ``training.ddpg`` (``mddpg``, ``ddpg``); the others go through
``training.baselines``."""
NOISES = ("gaussian", "ou")
TEACHER_VIEWS = ("full", "observation")
"""What a teaching planner may read (``TrainConfig.teacher_view``)."""
ACTOR_ARCHS = ("mlp", "sets")
LEARNER_PRECISIONS = ("float32", "bfloat16")
"""The arithmetics of the updates (``TrainConfig.learner_precision``)."""


class ConfigError(ValueError):
    """A training configuration field holds a value it cannot take."""


def train_episode_seed(seed: int, env_index: int, episode: int) -> int:
    """The reset seed of training episode ``episode`` of environment ``env_index`` in a run seeded ``seed``."""
    if not (0 <= env_index < 9 and 0 <= episode < 100_000):
        raise ConfigError(f"training episode seeds cover 9 environments of 100000 episodes, got {env_index}, {episode}")
    return TRAIN_SEED_BASE + seed * 1_000_000 + env_index * 100_000 + episode


def bc_weight_at(config: TrainConfig, step: int) -> float:
    """The cloning weight after ``step`` environment steps: ``bc_weight`` falling linearly to ``bc_weight_final``
    over the first ``bc_decay`` of ``total_steps`` (constant if ``bc_weight_final`` is None)."""
    if config.bc_weight_final is None:
        return float(config.bc_weight)
    frac = min(1.0, step / max(1.0, config.bc_decay * config.total_steps))
    return float(config.bc_weight + frac * (config.bc_weight_final - config.bc_weight))


def demo_episode_seed(seed: int, episode: int) -> int:
    """The reset seed of demonstration episode ``episode`` in a run seeded ``seed`` (disjoint from training)."""
    if not 0 <= episode < 100_000:
        raise ConfigError(f"demonstration episode seeds cover 100000 episodes, got {episode}")
    return TRAIN_SEED_BASE + seed * 1_000_000 + 900_000 + episode


@dataclass
class CurriculumStage:
    """One stage of the curriculum: until ``until`` (a fraction of ``total_steps``), episodes use these limits."""

    until: float
    """Fraction of the run's environment steps at which this stage ends (0, 1]."""
    max_target_distance: float
    """Largest start-to-target distance sampled in this stage, metres (the scene's ``agent.max_target_distance``)."""
    movers: int
    """How many of the scene's movers take part; the others are left out of the episode (their observation rows
    are filled with a far-away placeholder, so the observation keeps its size)."""


def field_docs(cls: type) -> dict[str, str]:
    """Each dataclass field's docstring (the string literal under it in the source), by field name."""
    import ast
    import inspect

    (node,) = ast.parse(inspect.getsource(cls)).body
    docs: dict[str, str] = {}
    body = node.body if isinstance(node, ast.ClassDef) else []
    for field_node, doc in zip(body, body[1:], strict=False):
        if (
            isinstance(field_node, ast.AnnAssign)
            and isinstance(field_node.target, ast.Name)
            and isinstance(doc, ast.Expr)
            and isinstance(doc.value, ast.Constant)
            and isinstance(doc.value.value, str)
        ):
            docs[field_node.target.id] = " ".join(doc.value.value.split())
    return docs


def field_value(name: str, value: Any, hint: Any) -> Any:
    """``value`` as a field of type ``hint`` wants it (integers taken for floats, lists for tuples), or
    ``ConfigError`` naming the field and what it expects."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if hint is Any:
        return value
    if origin in (types.UnionType, typing.Union):
        if value is None and type(None) in args:
            return None
        (inner,) = (a for a in args if a is not type(None))
        return field_value(name, value, inner)
    if hint is bool and isinstance(value, bool):
        return value
    if hint is int and isinstance(value, int) and not isinstance(value, bool):
        return value
    if hint is float and isinstance(value, int | float) and not isinstance(value, bool):
        return float(value)
    if hint is str and isinstance(value, str):
        return value
    if origin is dict and isinstance(value, dict):
        return value
    if origin is tuple and isinstance(value, list | tuple):
        return tuple(field_value(f"{name}[{i}]", v, args[0]) for i, v in enumerate(value))
    if hint is CurriculumStage and isinstance(value, CurriculumStage):
        return value
    if hint is CurriculumStage and isinstance(value, dict):
        fields = typing.get_type_hints(CurriculumStage)
        if set(value) != set(fields):
            raise ConfigError(f"{name}: expected the fields {', '.join(fields)}, got {', '.join(value) or 'none'}")
        return CurriculumStage(**{k: field_value(f"{name}.{k}", v, fields[k]) for k, v in value.items()})
    expected = {bool: "true or false", int: "an integer", float: "a number", str: "a string"}.get(
        hint, "a table" if origin is dict else "a list" if origin is tuple else getattr(hint, "__name__", str(hint))
    )
    shown = "nothing" if value is None else f"{value!r} ({type(value).__name__})"
    raise ConfigError(f"{name}: expected {expected}, got {shown}")


@dataclass
class TrainConfig:
    """Hyperparameters of one DDPG (``predictor = "none"``) or MDDPG (MPC prediction in the observation) run."""

    algo: str = "mddpg"
    """``mddpg`` (the paper's method: observations carry the MPC prediction) or ``ddpg`` (current positions only)."""
    forecast: str = "mpc"
    """The predictor whose forecast MDDPG observes (``deck_sim.control.prediction.PREDICTOR_NAMES`` but ``none``):
    ``mpc``, the paper's; ``constant_velocity`` or ``stationary``; ``oracle``, the movers' true future, simulated
    ahead at every step (far costlier than the MPC forecast: ``benchmarks/step_speed.py --predictor oracle``): a
    privileged observation, for asking whether the learner can use a perfect forecast at all, never an agent to
    compare with the others. DDPG observes none."""
    scene: str = "deck1"
    """Scene name or TOML path."""
    scene_overrides: dict[str, Any] = field(default_factory=dict)
    """Scene fields as ``<section>__<field>`` (``deck_sim.load``'s overrides), for training and evaluation alike."""
    seed: int = 0
    """Seeds networks, noise, replay sampling and the training episodes."""
    total_steps: int = 50_000
    """Environment steps (decisions, 0.5 s each on the deck) to collect, summed over all environments."""

    # -- networks and optimisation (paper eq. 3-6) ------------------------------------------------------------
    hidden: tuple[int, ...] = (256, 256)
    """Hidden layer widths of the actor and of each critic (ReLU)."""
    actor_arch: str = "mlp"
    """The actor's network (the online actor's and the final fit's): ``mlp`` over the flat observation, or
    ``sets``: one encoder per set of obstacles (the movers, the statics), shared by every obstacle of its set and
    max-pooled, under an MLP head of ``hidden`` (``training.networks.SetActor``); the critic stays an MLP."""
    set_hidden: tuple[int, ...] = (128, 128)
    """Hidden layer widths of each set encoder of ``actor_arch = "sets"`` (ReLU after every layer)."""
    actor_lr: float = 3e-4
    """Adam learning rate of the actor."""
    critic_lr: float = 3e-4
    """Adam learning rate of the critic(s)."""
    gamma: float = 0.99
    """Discount factor of the TD target y = r + gamma * Q'(s', mu'(s')) (eq. 3)."""
    tau: float = 0.005
    """Soft target update rate theta' <- tau theta + (1 - tau) theta' (eq. 6)."""
    actor_average: float = 0.0
    """Rate of a slow Polyak average of the actor's weights, bar <- rate theta + (1 - rate) bar after every actor
    update (0: off). Training never reads it (a run with it makes the same updates as one without); the run
    exports it at its end as ``actor_avg.npz`` beside ``actor.npz``, so the two can be measured on the same
    held-out episodes. 1e-4 averages over roughly the last 10,000 actor updates. Not with the final fit
    (``polish_epochs``), which replaces the actor."""
    batch_size: int = 256
    """Transitions per update."""
    learner_precision: str = "float32"
    """The arithmetic of the updates' hidden layers: ``float32``, or ``bfloat16`` (CPU autocast: the hidden layers'
    matrix products in bfloat16 with float32 accumulation, the weights, optimiser state, every network's output
    layer, the TD target and the losses in float32). ``bfloat16`` is faster on a CPU with native bfloat16
    instructions (``benchmarks/train_speed.py --precisions``, docs/benchmarks.md). Acting, evaluation and the
    exported actors stay float32 either way."""
    buffer_size: int = 300_000
    """Replay capacity in transitions (demonstrations included; they are never overwritten)."""
    learning_starts: int = 2_000
    """Environment steps of exploration before the first update (uniform random actions until then)."""
    reward_scale: float = 1.0
    """Rewards are multiplied by this before learning (the logs report the unscaled episode reward)."""
    grad_clip: float = 0.0
    """Clip gradient norms of actor and critic to this value (0: no clipping)."""

    # -- exploration ------------------------------------------------------------------------------------------
    noise: str = "gaussian"
    """Exploration noise: ``gaussian`` (independent per step) or ``ou`` (Ornstein-Uhlenbeck, temporally correlated)."""
    noise_sigma: float = 0.3
    """Noise scale at the start of training, in action units ([-1, 1])."""
    noise_sigma_final: float = 0.05
    """Noise scale reached at the end of ``noise_decay`` (linear decay)."""
    noise_decay: float = 0.5
    """Fraction of ``total_steps`` over which the noise decays to ``noise_sigma_final``."""
    ou_theta: float = 0.15
    """Mean-reversion rate of the OU noise per step."""
    hold_prob: float = 0.0
    """Probability per step that an environment starts holding one action for several steps in place of the
    actor's (``training.noise.HeldActions``; 0: never)."""
    hold_steps: int = 8
    """Longest hold, in steps (each hold lasts a uniform whole number of steps in [1, hold_steps])."""
    hold_action: str = "stop"
    """The held action: ``stop`` (no displacement: brake and wait) or ``random`` (one uniform random action)."""

    # -- the switches measured against plain DDPG ------------------------------------------------------------
    obs_norm: bool = False
    """Running mean/variance normalisation of observations (statistics from collected data, clipped to +-10)."""
    twin_critics: bool = False
    """TD3: two critics, the TD target takes their minimum (``twin_min_weight``)."""
    twin_min_weight: float = 1.0
    """With ``twin_critics``, the TD target's weight on the smaller of the two target critics, the larger taking
    the rest: 1 is TD3's minimum, 0.5 their mean (Weighted Delayed DDPG, He and Hou 2020, weighs the minimum
    against the mean in the same spirit). The minimum lies half the critics' disagreement below their mean on every
    bootstrapped step, and the discount compounds that over the horizon."""
    critic_layer_norm: bool = False
    """A ``LayerNorm`` after each hidden layer of the critic (the actor unchanged): it bounds the features the Q
    values are read from, which keeps the critic's extrapolation to unseen actions and its bootstrapped targets in
    check (Ball et al. 2023, RLPD; Hiraoka et al. 2022, DroQ)."""
    actor_preact_weight: float = 0.0
    """Weight of a penalty on the actor's action before its tanh, ``u``: the actor's loss adds
    ``actor_preact_weight * mean(u**2)`` over the batch and the action's components, in the manner of the original
    SAC implementation's penalty on its Gaussian policy's pre-tanh mean (1e-3 times half its mean square; Haarnoja
    et al. 2018). Without it the
    actor can drive ``u`` far past the saturation of tanh (|u| of 20 and more), where the critic's gradient reaches
    it multiplied by ``1 - tanh(u)**2``, practically 0, and that action no longer learns. 0: off."""
    target_noise: float = 0.0
    """TD3 target policy smoothing: std of the clipped Gaussian noise added to mu'(s') (0: off)."""
    target_noise_clip: float = 0.5
    """Clip of the target smoothing noise."""
    policy_delay: int = 1
    """TD3 delayed actor: update the actor and the targets once every this many critic updates."""
    curriculum: tuple[CurriculumStage, ...] = ()
    """Stages over target distance and mover count (empty: the scene as it is from the first step)."""
    num_envs: int = 1
    """Environments stepped together; the actor acts on all of them in one batched forward pass."""
    env_worker: bool = False
    """Step the environments in a worker process while the learner updates (two cores overlap; same results)."""
    updates_per_step: float = 1.0
    """Gradient updates per collected environment step (update-to-data ratio; below 1 updates less often)."""
    her_ratio: float = 0.0
    """Hindsight goals (HER's ``future`` strategy, ``training.her``): the share of the agent's sampled transitions
    whose target is replaced by a position the agent reached later in the same episode, with the observation's
    target and the reward's attraction and goal terms recomputed for it. 0: off. Learns from the reward alone (no
    planner); needs an observation without ``route``."""
    n_step: int = 1
    """Transitions summed per critic target: the discounted rewards of the next ``n_step`` transitions of the
    episode, then gamma^n_step times the bootstrap (``training.her``). 1: the one-step target of eq. 3."""
    per_alpha: float = 0.0
    """Prioritised replay (Schaul et al. 2016, proportional): the agent's transitions are sampled with probability
    proportional to (|TD error| + ``per_eps``)^``per_alpha`` of their last update, a new one at the largest
    priority so far (demonstrations stay uniform, in their ``demo_fraction``). 0: uniform sampling."""
    per_beta: float = 0.4
    """Prioritised replay's importance-sampling exponent at the first update, raised linearly to 1 at
    ``total_steps``: the critic's squared errors are weighted by (N P(i))^-beta over the batch's largest weight."""
    per_eps: float = 1e-3
    """Added to |TD error| (scaled-reward units) so that no transition's priority falls to 0."""
    demo_episodes: int = 0
    """Episodes of the full-knowledge scripted planner placed in the replay buffer before training (DDPGfD)."""
    demo_noise: float = 0.0
    """Std of Gaussian noise added to the planner's actions while demonstrating (DART, Laskey et al. 2017): the
    planner then shows how it recovers from the agent's kind of errors; the clean action is the cloning target."""
    expert_relabel: bool = False
    """Label the agent's own transitions with the scripted planner's action in the same state (DAgger, Ross et al.
    2011, as an auxiliary cloning target): the planner is queried during training only; the actor still acts
    from the observation alone."""
    teacher_body: bool = False
    """Teach with the scripted planner that checks the agent's whole body on the way it will really go
    (``ScriptedPlanner.body``: an aircraft's nose and tail, and its tracker's kinematics) in its demonstrations
    and its labels; off: the planner that checks the agent's disc along its path."""
    teacher_view: str = "full"
    """What the teaching planner reads: ``full``, the task's privileged state (``Navigate.planner_view``: regime
    ``oracle-teacher``); ``observation``, only what the agent's own observation holds (``Navigate.observed_view``:
    the observed footprints, and the observed MPC forecast for MDDPG or none for DDPG, whose observation has
    none: regime ``planner``). ``observation`` needs every obstacle's footprint in the observation (scene fields
    ``episode.static_size``, ``episode.mover_size``, ``episode.obstacle_shape``) and a teaching field on."""
    demo_fraction: float = 0.25
    """Share of every batch drawn from the demonstrations (when there are any)."""
    bc_weight: float = 0.0
    """Weight of the behaviour-cloning term on demonstration samples in the actor loss (0: off)."""
    bc_weight_final: float | None = None
    """Cloning weight reached at the end of ``bc_decay`` (linear in environment steps, as the noise; ``None``: the
    weight stays ``bc_weight``). A falling weight hands the actor over from the planner to the critic. The schedule
    follows ``total_steps``: a run resumed with more steps recomputes the weight on the longer schedule."""
    bc_decay: float = 1.0
    """Fraction of ``total_steps`` over which the cloning weight falls to ``bc_weight_final``."""
    bc_slow_weight: float = 1.0
    """Relative weight, in the cloning loss, of the samples where the planner asked for less than ``bc_slow_below``
    of the full step (it yields, brakes or creeps into the goal): rare states where its choice matters most."""
    bc_slow_below: float = 0.9
    """Action norm below which a planner's action counts as slow for ``bc_slow_weight``."""
    q_filter: bool = True
    """Clone a demonstrated action only where the critic rates it above the actor's own (Nair et al. 2018)."""
    bc_normalise_q: bool = True
    """With a cloning term, divide the Q term of the actor loss by the batch's mean |Q| (TD3+BC, Fujimoto and Gu
    2021), so that ``bc_weight`` weighs cloning against a Q term of size one whatever the reward scale."""
    polish_epochs: int = 0
    """After the last environment step, fit a freshly initialised actor to the planner's action on every labelled
    transition of the replay buffer (demonstrations and relabelled agent states) for this many epochs: the cloning
    loss alone, minibatches of ``batch_size``, Adam from ``polish_lr`` annealed to 0 by a cosine. This is DAgger's
    supervised step on the aggregated data (its measured effect: ``docs/training.md``, "Switches and their
    measured effects"). 0: off. A finished run can be polished later
    (``--resume --set polish_epochs=N``)."""
    polish_lr: float = 1e-3
    """Starting learning rate of the final cloning fit (``polish_epochs``)."""
    polish_hidden: tuple[int, ...] = ()
    """Hidden layer widths of the actor the final cloning fit trains (empty: ``hidden``, the online actor's). A
    wider fit matches the planner's labels more closely (``benchmarks/cloning.py``); the exported actor then has
    these widths, and the critic keeps ``hidden``."""
    dagger_steps: int = 0
    """After the final cloning fit, a DAgger round (Ross et al. 2011) on the fitted actor's own states: the fitted
    actor drives the training environments for this many environment steps, greedy (no noise) and without updates
    (nor normaliser changes), the planner labels every state it meets, and then ``polish_epochs`` fit a fresh actor
    again on every labelled transition, these included. 0: off. Needs ``polish_epochs`` and ``expert_relabel``. A
    fitted run can be given the round later (``--resume --set dagger_steps=N``); a round stopped before its fit
    is started again on resume. Keep the buffer large enough (``buffer_size``): the round's transitions overwrite
    the oldest online ones once it is full."""
    pretrain_updates: int = 0
    """Updates on the demonstrations alone before any interaction (DQfD's pre-training phase): the critic learns
    their TD targets, the actor clones them (no Q term: a critic that has seen only demonstrations cannot yet
    judge other actions)."""

    # -- evaluation, logging, checkpoints ----------------------------------------------------------------------
    eval_every: int = 10_000
    """Evaluate the greedy actor every this many environment steps (0: only at the end)."""
    eval_episodes: int = 20
    """Episodes per evaluation."""
    eval_seed: int = 500
    """Seed of the evaluation environment (consecutive episodes; held out: below ``TRAIN_SEED_BASE``)."""
    checkpoint_every: int = 10_000
    """Write a resumable checkpoint every this many environment steps (0: only at the end)."""
    log_every: int = 1_000
    """Write a CSV / TensorBoard row of training statistics every this many environment steps."""
    torch_threads: int = 1
    """Threads torch may use (1 keeps runs bit-identical and leaves the other core to the physics)."""

    extra: dict[str, Any] = field(default_factory=dict)
    """Free-form notes stored with the run (e.g. the preset's name); not read by the trainer."""

    @property
    def regime(self) -> str:
        """What the run learns from (``deck_sim.policies.regimes``): ``reward`` unless a teaching field is on, then
        ``planner`` or ``oracle-teacher`` by what the teacher reads (``teacher_view``)."""
        return config_regime(self.to_dict())

    @property
    def teacher_policy_view(self) -> str:
        """The teaching planner's ``deck_sim.policies.ScriptedPolicy`` view: ``full``, or the agent's own
        observation, with its forecast (MDDPG) or without (DDPG: ``observation-without-forecast``)."""
        if self.teacher_view == "full":
            return "full"
        return "observation" if self.predictor != "none" else "observation-without-forecast"

    @property
    def predictor(self) -> str:
        """The predictor filling the observation: ``forecast`` (``mpc``) for MDDPG, ``none`` for DDPG."""
        return self.forecast if self.algo == "mddpg" else "none"

    def _check_observed_footprints(self) -> None:
        """``ConfigError`` unless the scene, with the run's overrides, observes every obstacle's footprint."""
        from deck_sim.scenes import SceneSpecError, load_scene

        try:
            episode = load_scene(self.scene).episode
        except SceneSpecError as err:
            raise ConfigError(f"scene: {err}") from err
        off = [key for key in agents.OBSERVED_FIELDS
               if not self.scene_overrides.get(key, getattr(episode, key.removeprefix("episode__")))]
        if off:
            raise ConfigError(f"teacher_view: 'observation' plans from every obstacle's footprint in the observation; "
                              f"set scene_overrides {', '.join(f'{k} = true' for k in off)}")

    def validate(self) -> TrainConfig:
        """Raise ``ConfigError`` naming the first field with an impossible value; return self."""
        if self.algo not in ALGOS:
            raise ConfigError(f"algo: expected one of {', '.join(ALGOS)}, got {self.algo!r}")
        if self.forecast not in PREDICTOR_NAMES or self.forecast == "none":
            names = ", ".join(p for p in PREDICTOR_NAMES if p != "none")
            raise ConfigError(f"forecast: expected one of {names}, got {self.forecast!r} (DDPG is MDDPG without one)")
        if self.algo != "mddpg" and self.forecast != "mpc":
            raise ConfigError(f"forecast: {self.algo} observes no forecast, got forecast = {self.forecast!r}")
        if self.forecast != "mpc" and self.regime != "reward":
            raise ConfigError(f"forecast: a teacher plans on the MPC forecast, so a taught run observes it too; got "
                              f"forecast = {self.forecast!r} in regime {self.regime!r}")
        if not 0.0 <= self.actor_average < 1.0:
            raise ConfigError(f"actor_average: must lie in [0, 1), got {self.actor_average!r}")
        if self.actor_average and self.polish_epochs:
            raise ConfigError("actor_average: the final fit (polish_epochs) replaces the actor; use one or the other")
        if self.noise not in NOISES:
            raise ConfigError(f"noise: expected one of {', '.join(NOISES)}, got {self.noise!r}")
        if not 0.0 <= self.hold_prob <= 1.0:
            raise ConfigError(f"hold_prob: must lie in [0, 1], got {self.hold_prob!r}")
        if isinstance(self.hold_steps, bool) or not isinstance(self.hold_steps, int) or self.hold_steps < 1:
            raise ConfigError(f"hold_steps: must be an integer >= 1, got {self.hold_steps!r}")
        if self.hold_action not in HOLD_ACTIONS:
            raise ConfigError(f"hold_action: expected one of {', '.join(HOLD_ACTIONS)}, got {self.hold_action!r}")
        if not 0 <= self.seed < 4_000:
            raise ConfigError(f"seed: must lie in [0, 4000) (episode seeds must fit in 32 bits), got {self.seed!r}")
        if self.num_envs > 9:
            raise ConfigError(f"num_envs: at most 9, got {self.num_envs!r}")
        positive = ("total_steps", "batch_size", "buffer_size", "num_envs", "policy_delay", "eval_episodes")
        for name in positive:
            if getattr(self, name) < 1:
                raise ConfigError(f"{name}: must be at least 1, got {getattr(self, name)!r}")
        if isinstance(self.polish_epochs, bool) or not isinstance(self.polish_epochs, int) or self.polish_epochs < 0:
            raise ConfigError(f"polish_epochs: must be an integer >= 0, got {self.polish_epochs!r}")
        if self.polish_epochs and not (self.expert_relabel or self.demo_episodes):
            raise ConfigError("polish_epochs: needs labelled transitions (expert_relabel or demo_episodes)")
        if isinstance(self.dagger_steps, bool) or not isinstance(self.dagger_steps, int) or self.dagger_steps < 0:
            raise ConfigError(f"dagger_steps: must be an integer >= 0, got {self.dagger_steps!r}")
        if self.dagger_steps and not (self.polish_epochs and self.expert_relabel):
            raise ConfigError(
                "dagger_steps: needs the final fit (polish_epochs) and the planner's labels (expert_relabel)"
            )
        if not self.bc_slow_weight > 0.0:
            raise ConfigError(f"bc_slow_weight: must be positive, got {self.bc_slow_weight!r}")
        if self.bc_weight_final is not None and not 0.0 <= self.bc_weight_final:
            raise ConfigError(f"bc_weight_final: must be >= 0 or None, got {self.bc_weight_final!r}")
        if self.bc_weight_final is not None and self.bc_weight <= 0.0:
            raise ConfigError("bc_weight_final: the cloning term is off (bc_weight 0); a schedule needs bc_weight > 0")
        if not (math.isfinite(self.actor_preact_weight) and self.actor_preact_weight >= 0.0):
            raise ConfigError(f"actor_preact_weight: must be a finite number >= 0, got {self.actor_preact_weight!r}")
        if self.twin_min_weight != 1.0 and not self.twin_critics:
            raise ConfigError("twin_min_weight: weighs the twin critics, which are off (twin_critics false)")
        for name in ("gamma", "tau", "demo_fraction", "noise_decay", "bc_decay", "twin_min_weight"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ConfigError(f"{name}: must lie in [0, 1], got {value!r}")
        if not 0.0 <= self.her_ratio <= 1.0:
            raise ConfigError(f"her_ratio: must lie in [0, 1], got {self.her_ratio!r}")
        if isinstance(self.n_step, bool) or not isinstance(self.n_step, int) or not 1 <= self.n_step <= 100:
            raise ConfigError(f"n_step: must be an integer in [1, 100], got {self.n_step!r}")
        for name in ("per_alpha", "per_beta"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ConfigError(f"{name}: must lie in [0, 1], got {getattr(self, name)!r}")
        if not self.per_eps > 0.0:
            raise ConfigError(f"per_eps: must be positive, got {self.per_eps!r}")
        if self.teacher_view not in TEACHER_VIEWS:
            raise ConfigError(f"teacher_view: expected one of {', '.join(TEACHER_VIEWS)}, got {self.teacher_view!r}")
        if self.teacher_view == "observation":
            if not any(bool(getattr(self, name)) for name in TEACHING_FIELDS):
                raise ConfigError("teacher_view: 'observation' names what a teacher reads, but no teaching field is "
                                  f"on ({', '.join(TEACHING_FIELDS)})")
            self._check_observed_footprints()
        if self.demo_noise < 0:
            raise ConfigError(f"demo_noise: must be >= 0, got {self.demo_noise!r}")
        for name in ("actor_lr", "critic_lr", "updates_per_step", "reward_scale", "polish_lr"):
            if not getattr(self, name) > 0.0:
                raise ConfigError(f"{name}: must be positive, got {getattr(self, name)!r}")
        if not self.hidden or any(int(h) < 1 for h in self.hidden):
            raise ConfigError(f"hidden: expected positive layer widths, got {self.hidden!r}")
        if self.actor_arch not in ACTOR_ARCHS:
            raise ConfigError(f"actor_arch: expected one of {', '.join(ACTOR_ARCHS)}, got {self.actor_arch!r}")
        if self.learner_precision not in LEARNER_PRECISIONS:
            raise ConfigError(f"learner_precision: expected one of {', '.join(LEARNER_PRECISIONS)}, "
                              f"got {self.learner_precision!r}")
        if not self.set_hidden or any(int(h) < 1 for h in self.set_hidden):
            raise ConfigError(f"set_hidden: expected positive layer widths, got {self.set_hidden!r}")
        if any(int(h) < 1 for h in self.polish_hidden):
            raise ConfigError(f"polish_hidden: expected positive layer widths (or none), got {self.polish_hidden!r}")
        last = 0.0
        for i, stage in enumerate(self.curriculum):
            if not last < stage.until <= 1.0:
                raise ConfigError(f"curriculum[{i}].until: must increase within (0, 1], got {stage.until!r}")
            if stage.movers < 0 or stage.max_target_distance <= 0:
                raise ConfigError(f"curriculum[{i}]: movers >= 0 and max_target_distance > 0, got {stage!r}")
            last = stage.until
        self._check_scene()
        return self

    def _check_scene(self) -> None:
        """``ConfigError`` unless the scene with the run's overrides is a valid scene, both as given and with the
        run's predictor (an option read from the forecast, for one, needs a predictor: MDDPG); the predictor
        itself is the algorithm's, not an override."""
        from deck_sim.scenes import SceneSpecError, load_scene

        if "episode__predictor" in self.scene_overrides:
            raise ConfigError(f"scene_overrides: episode__predictor is the algorithm's ({self.algo}: {self.predictor})"
                              "; leave it out")
        try:
            load_scene(self.scene, **self.scene_overrides)
            load_scene(self.scene, **{**self.scene_overrides, "episode__predictor": self.predictor})
        except SceneSpecError as err:
            raise ConfigError(f"scene {self.scene!r} with scene_overrides {self.scene_overrides}: {err}") from err
        if self.curriculum:
            from training.envs import stage_overrides

            for i, stage in enumerate(self.curriculum):
                staged = {**self.scene_overrides, **stage_overrides(self.scene, stage, self.scene_overrides)}
                try:
                    load_scene(self.scene, **staged)
                    load_scene(self.scene, **{**staged, "episode__predictor": self.predictor})
                except SceneSpecError as err:
                    raise ConfigError(f"curriculum[{i}]: scene {self.scene!r} in this stage: {err}") from err

    def to_dict(self) -> dict[str, Any]:
        """A JSON-serialisable copy."""
        d = dataclasses.asdict(self)
        d["hidden"] = list(self.hidden)
        d["polish_hidden"] = list(self.polish_hidden)
        d["set_hidden"] = list(self.set_hidden)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TrainConfig:
        """The inverse of ``to_dict``: each value checked against its field's type (integers are accepted for
        floats, lists for tuples); an unknown field or a value of the wrong type raises ``ConfigError``."""
        d = dict(d)
        stated = d.pop("regime", None)  # (``save`` records it beside the fields; it follows from them)
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - names)
        if unknown:
            raise ConfigError(f"unknown training config field(s): {', '.join(unknown)}")
        hints = typing.get_type_hints(cls)
        config = cls(**{name: field_value(name, value, hints[name]) for name, value in d.items()}).validate()
        if stated is not None and stated != config.regime:
            raise ConfigError(f"regime: the config says {stated!r}, but its fields make {config.regime!r}")
        return config

    def save(self, path: str | Path) -> None:
        """Write the config as JSON, with its ``regime``."""
        Path(path).write_text(json.dumps({**self.to_dict(), "regime": self.regime}, indent=2, sort_keys=True) + "\n")

    @classmethod
    def load(cls, path: str | Path) -> TrainConfig:
        """Read a config written by ``save``."""
        try:
            d = json.loads(Path(path).read_text())
        except (OSError, json.JSONDecodeError) as err:
            raise ConfigError(f"{path}: cannot read a training config: {err}") from err
        return cls.from_dict(d)


PRESETS: dict[str, dict[str, Any]] = {
    # the paper's recipe: plain DDPG, one environment, one update per step, Gaussian noise
    "paper": {},
    # the switches that pay on the physical deck (measured by benchmarks/learning.py)
    "tuned": {
        "obs_norm": True,
        "twin_critics": True,
        "target_noise": 0.2,
        "policy_delay": 2,
        "num_envs": 4,
        "env_worker": True,
        "updates_per_step": 0.5,
        "demo_episodes": 100,
        "hidden": (400, 300),
        "bc_weight": 20.0,
        "q_filter": False,
        "expert_relabel": True,
        "pretrain_updates": 3_000,
        "reward_scale": 0.1,
        "noise_sigma": 0.1,
    },
    # the tuned recipe's learning switches without its teacher: learns from the reward alone (regime ``reward``)
    "reward": {
        "obs_norm": True,
        "twin_critics": True,
        "target_noise": 0.2,
        "policy_delay": 2,
        "num_envs": 8,
        "env_worker": True,
        "updates_per_step": 0.25,
        "hidden": (400, 300),
        "reward_scale": 0.1,
        "noise_sigma": 0.1,
    },
}


def make_config(preset: str = "tuned", **fields: Any) -> TrainConfig:
    """A validated ``TrainConfig`` from a preset (``paper``, ``tuned`` or ``reward``) with ``fields`` overriding
    it."""
    if preset not in PRESETS:
        raise ConfigError(f"preset: expected one of {', '.join(PRESETS)}, got {preset!r}")
    values = {**PRESETS[preset], **fields}
    values.setdefault("extra", {})
    values["extra"] = {**values["extra"], "preset": preset}
    return TrainConfig.from_dict(values)


ABLATIONS: dict[str, dict[str, Any]] = {
    "obsnorm": {"obs_norm": False},
    "td3": {"twin_critics": False, "target_noise": 0.0, "policy_delay": 1},
    "vec": {"num_envs": 1, "updates_per_step": 1.0},
    "demos": {"demo_episodes": 0, "pretrain_updates": 0, "bc_weight": 0.0, "expert_relabel": False},
    "relabel": {"expert_relabel": False},
    "bc": {"bc_weight": 0.0},
}
"""What each ``-no-<switch>`` arm of ``arm_config`` turns off in the tuned recipe."""
ADDITIONS: dict[str, dict[str, Any]] = {
    "shape": {"scene_overrides": {"episode__obstacle_shape": True}},
    "decay": {"bc_weight_final": 2.0},
    "slow": {"bc_slow_weight": 5.0},
    "data": {"num_envs": 8, "updates_per_step": 0.125},
    "size": {"scene_overrides": {"episode__mover_size": True}},
    "oracle": {"forecast": "oracle"},
    "cvforecast": {"forecast": "constant_velocity"},
    "avg": {"actor_average": 1e-4},
    "polish": {"polish_epochs": 20},
    "moverframe": {"scene_overrides": {"episode__predicted_frame": "mover"}},
    "near": {"scene_overrides": {"episode__near_steps": 4}},
    "ego": {"scene_overrides": {"episode__frame": "agent"}},
    "widepolish": {"polish_epochs": 40, "polish_hidden": (512, 512, 512)},
    "route": {"scene_overrides": {"episode__route_steps": 10}},
    "sets": {"actor_arch": "sets"},
    "close": {"scene_overrides": {"episode__near_steps": 4, "episode__near_obstacles": True}},
    "body": {"teacher_body": True},
    "dagger": {"dagger_steps": 40_000},
    "her": {"her_ratio": 0.8},
    "nstep": {"n_step": 3},
    "per": {"per_alpha": 0.6, "per_beta": 0.4},
    "meanq": {"twin_min_weight": 0.5},
    "lookahead": {"scene_overrides": {"reward__lookahead_steps": 6}},
    "approach": {"scene_overrides": {"episode__predicted_approach": True}},
    "nearforecast": {"scene_overrides": {"episode__predicted_near": True}},
    "layernorm": {"critic_layer_norm": True},
    "preact": {"actor_preact_weight": 1e-3},
    "utd": {"updates_per_step": 1.0},
    "wait": {"hold_prob": 0.02, "hold_steps": 10, "hold_action": "stop"},
    "ez": {"hold_prob": 0.02, "hold_steps": 10, "hold_action": "random"},
    "curriculum": {
        "curriculum": (
            {"until": 0.1, "max_target_distance": 100.0, "movers": 2},
            {"until": 0.25, "max_target_distance": 150.0, "movers": 5},
        )
    },
}
"""What each ``-with-<switch>`` arm of ``arm_config`` adds to a recipe (``shape``: the obstacles' nearest points
and the movers' headings in the observation, scene field ``episode.obstacle_shape``; ``decay``: the cloning weight
falls linearly from the recipe's 20 to 2 over the run, handing the actor from the planner to the critic;
``slow``: the planner's slow actions (yielding, braking) weigh 5 times in the cloning loss; ``data``: 8
environments at 0.125 updates per step, four times the relabelled states per update, for runs several times
longer; ``size``: each mover's footprint size in the observation, scene field ``episode.mover_size``;
``polish``: 20 epochs of pure cloning on the whole buffer after the last step, ``polish_epochs``;
``moverframe``: the predicted positions as each mover's predicted displacement, ``episode.predicted_frame``;
``near``: the target and the surface's edges clipped to 4 steps' reach, ``episode.near_steps``; ``ego``: the
observation's vectors and the action in the agent's own axes, ``episode.frame = "agent"``; ``widepolish``: the
final fit, 40 epochs, trains a 512 x 512 x 512 actor, ``polish_hidden``; ``route``: the next 10 steps' reach
of the shortest way round the static obstacles in the observation, ``episode.route_steps``; ``sets``: the actor
reads the movers and the statics through one shared, max-pooled encoder per set, ``actor_arch = "sets"``;
``close``: the near field of ``near`` and, in it, every obstacle's nearest point at that scale,
``episode.near_obstacles``; ``body``: the teacher checks the agent's whole body on the way it will really go,
``teacher_body``; ``dagger``: after the final fit, the fitted actor drives 40,000 more steps, greedy and without
updates, the planner labels them and the fit is made again, ``dagger_steps``; ``her``: hindsight targets for 80 % of
the sampled transitions, ``her_ratio``; ``nstep``: 3-step returns, ``n_step``; ``per``: prioritised replay with
alpha 0.6 and beta from 0.4, ``per_alpha``; ``meanq``: the TD target on the mean of the twin critics rather
than their minimum, ``twin_min_weight = 0.5``; ``layernorm``: a ``LayerNorm`` after each hidden layer of the
critic, ``critic_layer_norm``; ``preact``: a penalty of 1e-3 on the actor's squared pre-tanh action,
``actor_preact_weight``; ``utd``: one update per environment step (the reward preset makes one per 4),
``updates_per_step = 1``; ``lookahead``: the reward's repulsion term reads each mover's
closest approach over the next 6 steps of the MPC forecast, scene field ``reward.lookahead_steps``, for DDPG and
MDDPG alike; ``approach``: each mover's closest approach on its forecast, time and distance, in MDDPG's
observation, ``episode.predicted_approach``; ``nearforecast``: the forecast at the near field's scale,
``episode.predicted_near`` (with ``close``, which gives the near field: ``reward-mddpg-with-close+nearforecast``);
``wait``: exploration that now and then stops the aircraft for 1-10
steps whatever the actor wants (2 % chance per step of starting such a hold, ``hold_prob``, ``hold_action =
"stop"``); ``ez``: the same holds with one uniform random action each (temporally extended epsilon-greedy);
``curriculum``: for the first 10 % of the run's steps 2 movers and targets at most 100 m away, until 25 % 5 movers
(deck 1's all) and at most 150 m, then the whole scene, ``curriculum`` (a stage also draws targets from the start
sites, so that short trips exist; the observation normaliser leaves out the rows padded for the movers a stage
leaves out; DDPG and MDDPG arms only);
``oracle``: MDDPG observes the movers' true future in place of the MPC forecast, ``forecast = "oracle"`` (a
privileged diagnostic); ``cvforecast``: a constant-velocity forecast, ``forecast = "constant_velocity"``; ``avg``:
the slow average of the actor exported as ``actor_avg.npz``, ``actor_average = 1e-4``).
Several switches join with ``+``:
``tuned-mddpg-with-data+size``, ``reward-mddpg-with-her+nstep``."""


def arm_config(
    arm: str, scene: str, steps: int, seed: int, eval_every: int = 5_000, eval_episodes: int = 50
) -> TrainConfig:
    """The config of a named recipe, as ``benchmarks/learning.py`` and ``scripts/train_shipped.py`` run them:
    ``<paper|tuned|reward>-<ddpg|mddpg>``, ``tuned-<algo>-no-<switch>`` (a switch of ``ABLATIONS`` turned off) or
    ``<preset>-<algo>-with-<switch>`` (one of ``ADDITIONS`` added), with held-out evaluations (and checkpoints)
    every ``eval_every`` steps."""
    parts = arm.split("-")
    if len(parts) < 2 or parts[0] not in PRESETS or parts[1] not in ALGOS:
        raise ConfigError(
            f"unknown recipe {arm!r}: expected <{'|'.join(PRESETS)}>-<ddpg|mddpg>[-no-<switch>|-with-<switch>]"
        )
    fields: dict[str, Any] = {}
    if len(parts) > 2:
        table = {"no": ABLATIONS, "with": ADDITIONS}.get(parts[2])
        switches = "-".join(parts[3:]).split("+")
        if table is None or any(sw not in table for sw in switches) or len(set(switches)) < len(switches):
            raise ConfigError(
                f"unknown switch in {arm!r}: expected -no-<{'|'.join(ABLATIONS)}> or -with-<{'|'.join(ADDITIONS)}> "
                "(several joined by '+', each once)"
            )
        for sw in switches:
            for k, v in table[sw].items():
                fields[k] = {**fields[k], **v} if k == "scene_overrides" and k in fields else v
    return make_config(
        parts[0],
        algo=parts[1],
        scene=scene,
        seed=seed,
        total_steps=steps,
        eval_every=eval_every,
        eval_episodes=eval_episodes,
        checkpoint_every=eval_every,
        extra={"recipe": arm},
        **fields,
    )

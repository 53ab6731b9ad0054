"""Training recipes as data: one TOML file per shipped recipe (``deck1.toml``, ``deck2.toml``, ``square.toml``:
taught by the full-knowledge planner; ``deck1-planner.toml``, ``deck2-planner.toml``: taught by the planner on
the agent's own observation; ``deck1-reward.toml``, ``deck2-reward.toml``, ``square-reward.toml``: from the
reward alone, the paper's protocol; ``deck1-multi.toml``: one actor shared by four aircraft at once, taught by the
full-knowledge prioritised planner, ``training.team``).

A recipe names its scene and one or two tables: ``[ddpg]`` for MDDPG and DDPG (a preset of
``training.config.PRESETS``, the training seeds, and any ``TrainConfig`` fields over the preset) and, optionally,
``[sb3]`` for the DQN and A2C baselines (seeds, steps and evaluation cadence, any field both configs share such as
``num_envs``; ``[sb3.dqn]`` and ``[sb3.a2c]`` hold each algorithm's own fields, ``training.baseline_config``).
``deck-sim train --recipe deck1 --algo mddpg --seed 0`` trains one seed; ``scripts/train_shipped.py`` trains every
seed of every agent and ships the result.
"""

from __future__ import annotations

import json
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from deck_sim import agents
from training.config import ConfigError, TrainConfig, make_config

RECIPE_DIR = Path(__file__).resolve().parent
BASELINE_FIELDS = ("steps", "eval_every", "eval_episodes")
"""The ``[sb3]`` fields passed to ``training.baselines.train_baseline``."""


@dataclass(frozen=True)
class Recipe:
    """One recipe file, parsed.

    Attributes:
        name: The file's stem (``deck1``).
        scene: The scene it trains on.
        preset: The ``TrainConfig`` preset MDDPG and DDPG start from.
        ddpg_seeds: Training seeds of MDDPG and DDPG; the shipped file acts by the mean of their actors.
        ddpg_fields: ``TrainConfig`` fields over the preset.
        sb3_seeds: Training seeds of DQN and A2C.
        sb3_fields: ``steps``, ``eval_every`` and ``eval_episodes`` of DQN and A2C, and any other field of their
            configs: shared ones at the top, each algorithm's own under its name (``{"dqn": {...}}``).
        has_sb3: Whether the recipe trains DQN and A2C at all (its file has an ``[sb3]`` table).
    """

    name: str
    scene: str
    preset: str
    ddpg_seeds: tuple[int, ...]
    ddpg_fields: dict[str, Any] = field(default_factory=dict)
    sb3_seeds: tuple[int, ...] = (0,)
    sb3_fields: dict[str, Any] = field(default_factory=dict)
    has_sb3: bool = True

    @property
    def algos(self) -> tuple[str, ...]:
        """The training algorithms this recipe trains, in the paper's ranking."""
        return ("mddpg", "ddpg", "dqn", "a2c") if self.has_sb3 else ("mddpg", "ddpg")

    def seeds(self, algo: str) -> tuple[int, ...]:
        """The training seeds of ``algo`` in this recipe."""
        if _trainer(algo) == "ddpg":
            return self.ddpg_seeds
        self._check_sb3(algo)
        return self.sb3_seeds

    def _check_sb3(self, algo: str) -> None:
        if not self.has_sb3:
            raise ConfigError(f"recipe {self.name} trains MDDPG and DDPG only (no [sb3] table), not {algo}")

    def steps(self, algo: str) -> int:
        """Environment steps of one run of ``algo``."""
        if _trainer(algo) == "ddpg":
            return int(self.ddpg_fields["total_steps"])
        self._check_sb3(algo)
        return int(self.sb3_fields["steps"])

    def config(self, algo: str, seed: int, **overrides: Any) -> TrainConfig:
        """The validated ``TrainConfig`` of one MDDPG or DDPG run of this recipe, ``overrides`` applied last."""
        if _trainer(algo) != "ddpg":
            raise ConfigError(f"recipe {self.name}: {algo} is a stable-baselines3 agent; use baseline_kwargs")
        fields = {**self.ddpg_fields, **overrides}
        fields["extra"] = {**fields.get("extra", {}), "recipe": self.name}
        return make_config(self.preset, algo=algo, scene=self.scene, seed=seed, **fields)

    def baseline_kwargs(self, algo: str) -> dict[str, Any]:
        """Keyword arguments of ``training.baselines.train_baseline`` for a DQN or A2C run of this recipe."""
        if _trainer(algo) != "sb3":
            raise ConfigError(f"recipe {self.name}: {algo} trains with training.ddpg; use config")
        self._check_sb3(algo)
        shared = {k: v for k, v in self.sb3_fields.items() if k not in ("dqn", "a2c")}
        return {**shared, **self.sb3_fields.get(algo, {})}


    def run(self, algo: str, seed: int, steps: int | None = None, **fields: Any) -> TrainConfig | dict[str, Any]:
        """What one run of ``algo`` trains with: MDDPG and DDPG its ``TrainConfig`` (``config``), DQN and A2C the
        keyword arguments of ``training.baselines.train_baseline`` (``baseline_kwargs`` with ``algo``, ``scene``
        and ``seed``); ``steps`` (None: the recipe's) and ``fields`` applied over the recipe."""
        if _trainer(algo) == "ddpg":
            return self.config(algo, seed, **fields, **({} if steps is None else {"total_steps": steps}))
        kwargs = {"algo": algo, "scene": self.scene, "seed": seed, **self.baseline_kwargs(algo), **fields}
        return kwargs if steps is None else {**kwargs, "steps": steps}


def _trainer(algo: str) -> str:
    if algo not in agents.ALGOS:
        raise ConfigError(f"algo: expected one of {', '.join(agents.ALGOS)}, got {algo!r}")
    return agents.AGENTS[algo].trainer


def recipe_names() -> list[str]:
    """The recipes shipped with the package."""
    return sorted(p.stem for p in RECIPE_DIR.glob("*.toml"))


def load_recipe(name_or_path: str | Path) -> Recipe:
    """A shipped recipe by name (``deck1``) or a recipe file by path; ``ConfigError`` naming the problem."""
    path = Path(name_or_path)
    if path.suffix != ".toml":
        if str(name_or_path) not in recipe_names():
            raise ConfigError(f"unknown recipe {str(name_or_path)!r}; known recipes: {', '.join(recipe_names())}")
        path = RECIPE_DIR / f"{name_or_path}.toml"
    try:
        data = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"recipe file {path} does not exist") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise ConfigError(f"{path.name}: not valid TOML: {err}") from None
    unknown = sorted(set(data) - {"scene", "ddpg", "sb3"})
    if unknown:
        raise ConfigError(f"{path.name}: unknown key(s) {', '.join(unknown)}; expected scene, [ddpg] and [sb3]")
    if not isinstance(data.get("scene"), str):
        raise ConfigError(f"{path.name}: scene: expected a scene name, got {data.get('scene')!r}")
    ddpg = dict(data.get("ddpg", {}))
    sb3 = dict(data.get("sb3", {}))
    fixed = sorted({"algo", "scene", "seed"} & set(ddpg))
    if fixed:
        raise ConfigError(f"{path.name} [ddpg]: {', '.join(fixed)} set by the run (--algo, the recipe's scene, "
                          "seeds), not by the recipe")
    recipe = Recipe(
        name=path.stem,
        scene=data["scene"],
        preset=str(ddpg.pop("preset", "tuned")),
        ddpg_seeds=_seeds(ddpg.pop("seeds", [0]), f"{path.name} [ddpg] seeds"),
        ddpg_fields=ddpg,
        sb3_seeds=_seeds(sb3.pop("seeds", [0]), f"{path.name} [sb3] seeds"),
        sb3_fields=sb3,
        has_sb3="sb3" in data,
    )
    missing = [k for k in ("total_steps",) if k not in ddpg]
    missing += [k for k in BASELINE_FIELDS if k not in sb3] if recipe.has_sb3 else []
    if missing:
        raise ConfigError(f"{path.name}: missing field(s) {', '.join(missing)}")
    from training.baseline_config import baseline_config

    for algo in ("dqn", "a2c") if recipe.has_sb3 else ():  # every [sb3] field is checked now, not at training time
        own = sb3.get(algo, {})
        if not isinstance(own, dict):
            raise ConfigError(f"{path.name} [sb3] {algo}: expected a table of {algo} fields, got {own!r}")
        budget = sorted(set(own) & {"seeds", *BASELINE_FIELDS})
        if budget:
            raise ConfigError(f"{path.name} [sb3.{algo}]: {', '.join(budget)} belong(s) in [sb3], the same for DQN "
                              "and A2C")
        fields = {k: v for k, v in recipe.baseline_kwargs(algo).items() if k not in BASELINE_FIELDS}
        for key in ("algo", "scene", "seed", "total_steps"):
            if key in fields:
                raise ConfigError(f"{path.name} [sb3]: {key} is set by the recipe's scene, seeds and steps")
        try:
            baseline_config(algo, **fields)
        except ConfigError as err:
            raise ConfigError(f"{path.name} [sb3{'.' + algo if algo in sb3 else ''}]: {err}") from None
    recipe.config("mddpg", recipe.ddpg_seeds[0])  # every [ddpg] field is checked now, not at training time
    return recipe


def _seeds(value: Any, where: str) -> tuple[int, ...]:
    if not isinstance(value, list) or not value or not all(isinstance(s, int) and s >= 0 for s in value):
        raise ConfigError(f"{where}: expected a non-empty list of seeds >= 0, got {value!r}")
    if len(set(value)) < len(value):
        raise ConfigError(f"{where}: each seed once, got {value!r}")
    return tuple(value)


def config_differences(run_dir: str | Path, plan: TrainConfig | dict[str, Any]) -> list[str]:
    """The fields in which the run recorded in ``run_dir/config.json`` differs from ``plan`` (what ``Recipe.run``
    returns: MDDPG's or DDPG's ``TrainConfig``, or DQN's or A2C's ``train_baseline`` keywords), sorted; empty if
    the run is that plan's. A ``config.json`` that cannot be read as the plan's kind of config gives
    ``["config.json"]``. A DQN or A2C config of the first format (``steps`` without ``total_steps``) did not record
    its evaluation and logging fields (``FIRST_FORMAT_UNRECORDED``), which says nothing of what the run used: they
    are not compared."""
    from training.baseline_config import baseline_config
    from training.baselines import saved_baseline_config
    from training.checkpoints import CheckpointError

    try:
        if isinstance(plan, TrainConfig):
            want, have = plan.to_dict(), TrainConfig.load(Path(run_dir) / "config.json").to_dict()
        else:
            fields = {k: v for k, v in plan.items() if k not in ("algo", "steps")}
            if plan.get("steps") is not None:
                fields["total_steps"] = plan["steps"]
            want = baseline_config(plan["algo"], **fields).to_dict()
            have = saved_baseline_config(run_dir).to_dict()
            saved = json.loads((Path(run_dir) / "config.json").read_text())
            if "steps" in saved and "total_steps" not in saved:  # (the first format)
                for name in FIRST_FORMAT_UNRECORDED:
                    if name not in saved and name not in saved.get("sb3", {}):
                        want.pop(name, None)
                        have.pop(name, None)
    except (ConfigError, CheckpointError):
        return ["config.json"]
    return differing_fields(want, have)


FIRST_FORMAT_UNRECORDED = ("eval_every", "eval_episodes", "eval_seed", "log_every")
"""The fields of a DQN or A2C run that the first format of its ``config.json`` did not record."""


def shipped_differences(scene: str, agent: str) -> list[str]:
    """The fields in which the runs behind the shipped ``agent`` of ``scene`` (their logs beside the actor,
    ``deck_sim.policies.shipped_logs``) differ from what the agent's recipe gives each seed now
    (``config_differences``), sorted; empty where every shipped run is the recipe's or no logs are shipped. A
    recipe changed after its agent shipped makes it non-empty until ``scripts/train_shipped.py`` trains again."""
    from deck_sim.policies import shipped_logs

    recipe = load_recipe(agents.recipe_name(agent, scene))
    algo = agents.training_algo(agent)
    return sorted({f for folder, seed in shipped_logs(agent, scene) if seed is not None
                   for f in config_differences(folder, recipe.run(algo, seed))})


def shipped_drift(scene: str, agent: str) -> str | None:
    """``shipped_differences`` as the phrase every table that lists shipped agents puts beside one ("trained with
    other scene_overrides than `deck2-reward` gives now"); None where there is nothing to say."""
    fields = shipped_differences(scene, agent)
    return (f"trained with other {', '.join(fields)} than `{agents.recipe_name(agent, scene)}` gives now"
            if fields else None)


NOTES = frozenset({"extra"})
"""The config keys that hold notes stored with a run (the recipe's or preset's name), which the trainer never
reads: two runs that differ in them alone are the same training."""


def differing_fields(want: dict[str, Any], have: dict[str, Any]) -> list[str]:
    """The keys of two configs' ``to_dict`` forms whose values differ (a missing key counts), sorted; the notes
    (``NOTES``: a recipe renamed since a run was made) do not count."""
    return sorted(k for k in want.keys() | have.keys() if k not in NOTES
                  and json.dumps(want.get(k), sort_keys=True) != json.dumps(have.get(k), sort_keys=True))

"""Recipes as data: the shipped agents are runs of their recipe file, ``deck-sim train --recipe`` and
``scripts/train_shipped.py`` build the same configuration from it, and a bad recipe is refused by name."""

from __future__ import annotations

import importlib.util
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from deck_sim.agents import AGENTS, recipe_name, training_algo
from deck_sim.cli import main
from deck_sim.policies import EnsemblePolicy, load_actor, shipped_policy_path
from training.config import ConfigError, TrainConfig
from training.recipes import load_recipe, recipe_names

ROOT = Path(__file__).resolve().parents[1]
SCENES = ("deck1", "deck2", "square")


def _train_shipped():
    spec = importlib.util.spec_from_file_location("train_shipped", ROOT / "scripts" / "train_shipped.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _without_notes(config: dict) -> dict:
    """A config as JSON, less the free-form ``extra`` notes (not read by the trainer)."""
    return {k: v for k, v in json.loads(json.dumps(config)).items() if k != "extra"}


def test_every_shipped_scene_has_a_recipe_and_a_reward_alone_recipe_and_the_decks_a_planner_recipe():
    planner = ("deck1-planner", "deck2-planner")
    assert recipe_names() == sorted([*SCENES, *(f"{s}-reward" for s in SCENES), *planner, "deck1-multi"])
    for name in planner:
        recipe = load_recipe(name)
        assert recipe.algos == ("mddpg", "ddpg")  # taught agents only: DQN and A2C learn from the reward
        with pytest.raises(ConfigError, match="trains MDDPG and DDPG only"):
            recipe.baseline_kwargs("dqn")
        taught = load_recipe(recipe.scene).config("mddpg", 0).to_dict()
        mine = recipe.config("mddpg", 0).to_dict()
        # the full-knowledge teacher's recipe, with what the planner reads added to the observation
        assert {k for k in taught if taught[k] != mine[k]} <= {"teacher_view", "scene_overrides", "extra", "seeds"}
        assert mine["scene_overrides"] == {**taught["scene_overrides"], **mine["scene_overrides"]}
    for scene in SCENES:
        assert load_recipe(scene).scene == load_recipe(f"{scene}-reward").scene == scene
        for agent in ("mddpg-reward", "ddpg-reward"):
            assert recipe_name(agent, scene) == f"{scene}-reward"
            config = load_recipe(recipe_name(agent, scene)).config(training_algo(agent), 2)
            assert config.regime == "reward" and config.algo == agent.split("-")[0]
            assert not (config.demo_episodes or config.bc_weight or config.expert_relabel or config.polish_epochs)
        # DQN and A2C get the scene fields of MDDPG and DDPG (the same observation, less the forecast MDDPG adds)
        reward = load_recipe(f"{scene}-reward")
        for algo in ("dqn", "a2c"):
            assert reward.baseline_kwargs(algo).get("scene_overrides", {}) == \
                reward.config("mddpg", 0).scene_overrides == reward.config("ddpg", 0).scene_overrides
        assert recipe_name("mddpg", scene) == scene and training_algo("mddpg") == "mddpg"


def test_train_help_lists_every_shipped_recipe(capsys):
    with pytest.raises(SystemExit) as done:
        main(["train", "--help"])
    assert done.value.code == 0
    help_text = re.sub(r"-\s+", "-", " ".join(capsys.readouterr().out.split()))  # undo argparse's wrapping
    listed = re.search(r"a shipped recipe \(([^:]*):", help_text).group(1)
    assert listed.split(", ") == recipe_names()


SHIPPED_SEEDS = {"deck1": (0, 1, 2), "deck2": (0, 1, 2), "square": (0, 1, 2)}
"""The training seeds behind each scene's shipped oracle-teacher MDDPG and DDPG files."""


@pytest.mark.parametrize("scene", SCENES)
def test_the_shipped_mddpg_and_ddpg_are_runs_of_their_recipe(scene):
    """Every actor behind a shipped file was trained with exactly its recipe's config (fields the trainer gained
    after a run was made read as their defaults): changing a recipe means training and shipping again."""
    recipe = load_recipe(scene)
    defaults = TrainConfig().to_dict()
    for algo in ("mddpg", "ddpg"):
        policy = load_actor(shipped_policy_path(algo, scene))
        members = policy.members if isinstance(policy, EnsemblePolicy) else [policy]
        assert tuple(m.meta["config"]["seed"] for m in members) == recipe.seeds(algo) == SHIPPED_SEEDS[scene], \
            (scene, algo)
        for member in members:
            shipped = member.meta["config"]
            expected = _without_notes(recipe.config(algo, shipped["seed"]).to_dict())
            stored = {**_without_notes(defaults), **_without_notes(shipped)}
            assert stored == expected, (scene, algo, {k for k in expected if stored.get(k) != expected[k]})
            assert member.meta["polished"]  # each run's final, fitted actor (training.loop.shipped_actor)
        assert recipe.steps(algo) == 160_000


@pytest.mark.parametrize(
    ("scene", "algo", "seed"),
    [("deck1", "mddpg", 1), ("deck2", "ddpg", 0), ("square", "dqn", 0), ("deck1", "mddpg-reward", 2),
     ("deck2", "ddpg-reward", 0), ("deck1", "ddpg-planner", 1), ("deck1", "dqn-reward", 1),
     ("square", "a2c-reward", 2)],
)
def test_train_recipe_is_what_train_shipped_runs(scene, algo, seed, capsys):
    recipe = recipe_name(algo, scene)
    assert main(["train", "--recipe", recipe, "--algo", training_algo(algo), "--seed", str(seed),
                 "--print-config"]) == 0
    printed = json.loads(capsys.readouterr().out)
    script = _train_shipped()
    planned = script.run_config(scene, algo, script.default_steps(scene, algo), seed, {})
    assert script.run_folder(Path("runs"), scene, algo, seed) == Path(f"runs/{recipe}-{training_algo(algo)}-seed{seed}")
    if isinstance(planned, TrainConfig):
        assert printed == json.loads(json.dumps({**planned.to_dict(), "regime": planned.regime}))
        assert printed["extra"]["recipe"] == recipe
        regime = {"reward": "reward", "planner": "planner"}.get(algo.rpartition("-")[2], "oracle-teacher")
        assert printed["regime"] == regime
    else:  # the keywords of train_baseline, as the config it builds from them
        from training.baseline_config import baseline_config

        fields = {k: v for k, v in planned.items() if k not in ("algo", "steps")}
        assert printed == baseline_config(training_algo(algo), **fields, total_steps=planned["steps"]).to_dict()
        assert printed["total_steps"] == load_recipe(recipe).steps(training_algo(algo))
        if AGENTS[algo].recipe == "reward":  # DDPG's budget, with the fields tuned for the algorithm
            assert printed["total_steps"] == load_recipe(recipe).steps("mddpg")
            assert load_recipe(recipe).baseline_kwargs(training_algo(algo)).items() <= {
                **planned, **printed}.items()


def test_train_options_apply_over_the_recipe_and_contradictions_are_refused(capsys):
    args = ["train", "--recipe", "deck1", "--algo", "ddpg", "--steps", "5000", "--set", "batch_size=64",
            "--print-config"]
    assert main(args) == 0
    printed = json.loads(capsys.readouterr().out)
    assert (printed["total_steps"], printed["batch_size"], printed["teacher_body"]) == (5000, 64, True)
    for clash in (["--scene", "deck2"], ["--preset", "paper"]):
        assert main(["train", "--recipe", "deck1", *clash, "--print-config"]) == 2
        assert f"drop {clash[0]}" in capsys.readouterr().err
    assert main(["train", "--recipe", "nowhere", "--print-config"]) == 2
    assert ("unknown recipe 'nowhere'; known recipes: deck1, deck1-multi, deck1-planner, deck1-reward, deck2, "
            "deck2-planner, deck2-reward, square, square-reward") in capsys.readouterr().err


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ('scene = "deck1"\n[ddpg]\ntotal_steps = 10\n[sb3]\n', "missing field\\(s\\) steps, eval_every, eval_episodes"),
        ('scene = "deck1"\nteam = 3\n', "unknown key\\(s\\) team"),
        ('[ddpg]\ntotal_steps = 10\n', "scene: expected a scene name"),
        ('scene = "deck1"\n[ddpg]\nseeds = [0, 0]\n', "\\[ddpg\\] seeds: each seed once"),
        ('scene = "deck1"\n[ddpg]\ntotal_steps = 10\nwings = 2\n[sb3]\nsteps = 1\neval_every = 1\neval_episodes = 1\n',
         "unknown training config field\\(s\\): wings"),
        ("scene = \n", "not valid TOML"),
        ('scene = "deck1"\n[ddpg]\ntotal_steps = 10\n[sb3]\nsteps = 1\neval_every = 1\neval_episodes = 1\nwings = 2\n',
         "\\[sb3\\]: unknown dqn config field\\(s\\): wings"),
        ('scene = "deck1"\n[ddpg]\ntotal_steps = 10\n[sb3]\nsteps = 1\neval_every = 1\neval_episodes = 1\n'
         '[sb3.a2c]\nn_steps = 0\n', "\\[sb3.a2c\\]: n_steps: must be at least 1"),
        ('scene = "deck1"\n[ddpg]\ntotal_steps = 10\n[sb3]\nsteps = 1\neval_every = 1\neval_episodes = 1\nseed = 3\n',
         "\\[sb3\\]: seed is set by the recipe"),
        ('scene = "deck1"\n[ddpg]\ntotal_steps = 10\n[sb3]\nsteps = 1\neval_every = 1\neval_episodes = 1\n'
         '[sb3.a2c]\nsteps = 5\n', "\\[sb3.a2c\\]: steps belong\\(s\\) in \\[sb3\\]"),
        ('scene = "deck1"\n[ddpg]\ntotal_steps = 10\n[sb3]\nsteps = 1\neval_every = 1\neval_episodes = 1\ndqn = 5\n',
         "\\[sb3\\] dqn: expected a table of dqn fields"),
        ('scene = "deck1"\n[ddpg]\ntotal_steps = 10\n[sb3]\nsteps = 1\neval_every = 1\neval_episodes = 1\n'
         "num_envs = 10\n", "num_envs: at most 9"),
        ('scene = "deck1"\n[ddpg]\ntotal_steps = 10\nalgo = "mddpg-reward"\n[sb3]\nsteps = 1\neval_every = 1\n'
         "eval_episodes = 1\n", "\\[ddpg\\]: algo set by the run"),
    ],
)
def test_a_bad_recipe_file_is_refused_naming_the_problem(tmp_path, text, message):
    path = tmp_path / "mine.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message):
        load_recipe(path)


def test_a_reward_alone_agent_that_is_not_shipped_is_refused_with_the_command_that_trains_it(capsys):
    from deck_sim.policies import PolicyFileError

    with pytest.raises(PolicyFileError, match="no shipped mddpg-reward policy for scene 'harbour'"):
        shipped_policy_path("mddpg-reward", "harbour")
    with pytest.raises(PolicyFileError, match="deck-sim train --recipe harbour-reward --algo mddpg"):
        shipped_policy_path("mddpg-reward", "harbour")
    # an agent acting through the averaged actor: where it can ship, and how one run acts that way
    with pytest.raises(PolicyFileError, match=r"recipe deck1-reward keeps an averaged actor \(actor_average\).*"
                                              "deck-sim select RUN --averaged --out FILE"):
        shipped_policy_path("mddpg-reward-select", "deck1")
    with pytest.raises(SystemExit):  # a shipped agent's name, not a training algorithm
        main(["train", "--algo", "mddpg-reward", "--print-config"])
    assert "invalid choice: 'mddpg-reward'" in capsys.readouterr().err


def test_a_recipe_gives_dqn_and_a2c_their_shared_and_their_own_fields(tmp_path, capsys):
    path = tmp_path / "fair.toml"
    path.write_text('scene = "deck2"\n[ddpg]\npreset = "reward"\ntotal_steps = 1000\n[sb3]\nseeds = [0, 1]\n'
                    "steps = 5000\neval_every = 1000\neval_episodes = 5\nnum_envs = 4\n"
                    "[sb3.a2c]\nn_steps = 8\nent_coef = 0.01\n[sb3.dqn]\nlearning_starts = 500\n")
    recipe = load_recipe(path)
    assert recipe.baseline_kwargs("a2c") == {"steps": 5000, "eval_every": 1000, "eval_episodes": 5, "num_envs": 4,
                                             "n_steps": 8, "ent_coef": 0.01}
    assert recipe.baseline_kwargs("dqn")["learning_starts"] == 500 and "n_steps" not in recipe.baseline_kwargs("dqn")
    assert main(["train", "--recipe", str(path), "--algo", "a2c", "--seed", "1", "--print-config"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert (printed["scene"], printed["num_envs"], printed["n_steps"], printed["total_steps"]) == ("deck2", 4, 8, 5000)


def test_a_training_config_takes_training_algorithms_not_shipped_agent_names():
    from training.config import make_config

    with pytest.raises(ConfigError, match="algo: expected one of mddpg, ddpg, got 'mddpg-reward'"):
        make_config("reward", algo="mddpg-reward")


def test_train_shipped_refuses_an_agent_whose_recipe_the_scene_lacks():
    done = subprocess.run([sys.executable, "scripts/train_shipped.py", "--scenes", "square", "--algos",
                           "mddpg-planner"], cwd=ROOT, capture_output=True, text=True, timeout=300,
                          env={**os.environ, "MUJOCO_GL": "disable"})
    assert done.returncode != 0
    assert "square mddpg-planner: no recipe training/recipes/square-planner.toml" in done.stderr


def test_the_multi_aircraft_recipe_trains_a_shared_taught_actor_on_deck1_multi():
    from training.team import _refused, is_multi_agent

    recipe = load_recipe("deck1-multi")
    assert recipe.algos == ("mddpg", "ddpg") and recipe.scene == "deck1-multi"
    for algo in recipe.algos:
        config = recipe.config(algo, 0)
        assert is_multi_agent(config) and config.regime == "oracle-teacher"
        assert _refused(config) == []  # the shared trainer takes every field of the recipe


def test_shipped_differences_name_the_fields_a_recipe_changed_after_its_agent_shipped(tmp_path, monkeypatch):
    """The runs shipped beside an agent are compared with what its recipe gives each seed now; a DQN or A2C config
    of the first format, which did not record the evaluation fields, is compared on the fields it records."""
    import deck_sim.policies
    from training.recipes import shipped_differences

    recipe = load_recipe("deck1-reward")
    logs = {"mddpg-reward": [], "dqn-reward": []}
    for seed in (0, 1):
        folder = tmp_path / "mddpg" / f"seed{seed}"
        folder.mkdir(parents=True)
        recipe.run("mddpg", seed).save(folder / "config.json")
        logs["mddpg-reward"].append((folder, seed))
    plan = recipe.run("dqn", 0)  # the first format: the run's length as steps, the SB3 keywords under sb3
    first = {"algo": "dqn", "predictor": "none", "scene": plan["scene"], "seed": 0, "steps": plan["steps"],
             "scene_overrides": plan.get("scene_overrides", {}),
             "sb3": {k: v for k, v in plan.items() if k not in ("algo", "scene", "seed", "steps", "scene_overrides",
                                                                  "eval_every", "eval_episodes")}}
    (tmp_path / "dqn").mkdir()
    (tmp_path / "dqn" / "config.json").write_text(json.dumps(first))
    logs["dqn-reward"].append((tmp_path / "dqn", 0))
    monkeypatch.setattr(deck_sim.policies, "shipped_logs", lambda agent, scene: logs[agent])
    assert shipped_differences("deck1", "mddpg-reward") == []
    path = tmp_path / "mddpg" / "seed1" / "config.json"
    path.write_text(json.dumps({**json.loads(path.read_text()), "scene_overrides": {"episode__near_steps": 4},
                                "hidden": [64, 64]}))
    assert shipped_differences("deck1", "mddpg-reward") == ["hidden", "scene_overrides"]
    assert shipped_differences("deck1", "dqn-reward") == []
    path = tmp_path / "dqn" / "config.json"
    path.write_text(json.dumps({**first, "eval_episodes": 7}))  # (recorded: compared)
    assert shipped_differences("deck1", "dqn-reward") == ["eval_episodes"]
    path.write_text(json.dumps({**first, "sb3": {**first["sb3"], "gamma": 0.5}}))
    assert shipped_differences("deck1", "dqn-reward") == ["gamma"]

"""Generate ``docs/results.md``: the task-suite evaluation of every agent on every scene, beside the paper's tables.

    python scripts/make_results.py [--episodes 100] [--workers 2] [--agents ...] [--scenes ...] [--out runs/results]

Runs ``deck_sim.evaluation`` (the engine of ``deck-sim eval``) on held-out episodes seeded 100000 + i, writes its
full report (JSON, CSV, Markdown, MCAP logs of the first two episodes of every scene and agent) to ``--out``, and
then ``docs/results.md`` with: the command and commit it came from, the machine; first the paper's comparison, every
run of the scenes' reward-alone recipes (``training/recipes/<scene>-reward.toml``, run folders in ``--runs`` or the
logs shipped with a reward-regime actor) measured seed by seed on the same held-out episodes (``training.heldout``),
as means over seeds with 95 % intervals over seeds and paired differences, then the same MDDPG and DDPG runs acting
through their averaged actors and their own critics' choice (``training.final_fit.PLAYS``, where the recipe keeps
an averaged actor); MDDPG against DDPG in the regimes that
also learn from a planner (``<scene>-planner`` and ``<scene>`` recipes) measured the same way (in both, a run trained
with another configuration than its recipe gives now is named with the command that retrains it, and not counted);
then how many
training seeds and episodes stand behind each shipped policy's number (training figures from
``deck_sim/trained/results.json``), the tables, the targets checked against the numbers, learning curves from the
training runs' ``eval.csv`` logs (the ``runs/learning`` folders ``scripts/train_shipped.py`` trains in, where
present) and one trajectory plot per scene.
Nothing in ``docs/results.md`` is typed by hand.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MUJOCO_GL", "disable")

import argparse  # noqa: E402
import csv  # noqa: E402
import functools  # noqa: E402
import hashlib  # noqa: E402
import json  # noqa: E402
import shutil  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import asdict  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import NamedTuple  # noqa: E402

import numpy as np  # noqa: E402

from deck_sim.agents import AGENTS as AGENT_INFO  # noqa: E402
from deck_sim.agents import LEARNED, recipe_name, training_algo  # noqa: E402
from deck_sim.evaluation import (  # noqa: E402
    PAPER,
    EvalConfig,
    EvalResults,
    evaluate,
    machine,
    markdown_tables,
    plot_learning_curves,
    plot_trajectories,
    summarize_agent,
    write_report,
)
from deck_sim.metrics import mean_interval, paired_bootstrap_interval  # noqa: E402
from deck_sim.policies import TRAINED_DIR, load_actor, seeds_text, shipped_log_dir, shipped_logs  # noqa: E402
from deck_sim.policies.regimes import REGIMES, actor_regime, config_regime, regime_text  # noqa: E402
from deck_sim.progress import progress  # noqa: E402
from deck_sim.rollout import git_commit  # noqa: E402
from training.recipes import config_differences, load_recipe, recipe_names, shipped_drift  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
AGENTS = ("mddpg-reward,ddpg-reward,mddpg-reward-select,ddpg-reward-select,dqn-reward,a2c-reward,mddpg-planner,"
          "ddpg-planner,mddpg,ddpg,dqn,a2c,apf,astar,mpc,scripted-observed,scripted,scripted-body")


def training_figures(scene: str, agent: str) -> dict | None:
    """What ``scripts/train_shipped.py`` recorded about the shipped ``agent`` of ``scene`` (None if nothing)."""
    path = TRAINED_DIR / "results.json"
    if not path.exists():
        return None
    data = json.loads(path.read_text()).get(scene, {})
    if "train_steps" in data:  # the first format held MDDPG alone
        return data if agent == "mddpg" else None
    return data.get(agent)


def fingerprint(cfg: EvalConfig) -> str:
    """A digest of everything a scene's evaluation depends on: the settings, the Python sources of ``deck_sim``
    and ``training``, the scene files, the MJCF models and the policy files of its learned agents."""
    digest = hashlib.sha256(json.dumps(asdict(cfg), sort_keys=True).encode())
    files = sorted((ROOT / "deck_sim").rglob("*.py")) + sorted((ROOT / "training").rglob("*.py"))
    files += sorted((ROOT / "deck_sim" / "scenes").glob("*.toml"))
    files += sorted((ROOT / "deck_sim" / "assets").glob("*.xml"))
    files += [TRAINED_DIR / f"{s}_{a}.npz" for s in cfg.scenes for a in cfg.agents if a in LEARNED]
    for f in files:
        digest.update(str(f.relative_to(ROOT)).encode())
        digest.update(f.read_bytes())
    return digest.hexdigest()


NUMERIC = ("shortest_path", "ade", "fde", "path_length", "min_clearance", "reward")


def load_scene_report(folder: Path, cfg: EvalConfig, key: str) -> EvalResults | None:
    """The evaluation saved in ``folder`` if its fingerprint is ``key``, else None."""
    try:
        meta = json.loads((folder / "fingerprint.json").read_text())
        data = json.loads((folder / "summary.json").read_text())
    except (OSError, json.JSONDecodeError):
        return None
    if meta.get("key") != key:
        return None
    episodes = [
        {k: (float("nan") if v is None and k in NUMERIC else v) for k, v in r.items()} for r in data["episodes"]
    ]
    summaries = [summarize_agent(episodes, s, a) for s in {r["scene"] for r in episodes} for a in cfg.agents]
    return EvalResults(cfg, episodes, summaries, float(meta["wall_s"]), list(meta["logs"]))


def provenance(scenes: list[str], agents: list[str], episodes: int, missing: dict[str, list[str]]) -> list[str]:
    lines = [
        "| agent | scene | learnt from | training seeds | training steps (each seed) |"
        " training wall time (all seeds) | evaluation episodes |",
        "|---|---|---|---:|---:|---:|---:|",
    ]
    for scene in scenes:
        for agent in agents:
            if agent in missing[scene] and not made_for(agent, scene):
                continue  # (an agent acting through an averaged actor the scene's recipe does not keep)
            if agent in missing[scene]:
                lines.append(f"| {agent} | {scene} | - | no policy shipped yet: not evaluated (n/a) | - | - | 0 |")
            elif agent in LEARNED:
                fig = training_figures(scene, agent) or {}
                steps = f"{fig['train_steps']:,}" if "train_steps" in fig else "?"
                wall = f"{fig['train_wall_s'] / 60:.0f} min" if "train_wall_s" in fig else "?"
                seeds = fig.get("seeds") or [fig.get("seed", "?")]
                runs = seeds_text(seeds, fig.get("trained_seeds"))
                learnt = shipped_regime(scene, agent) or "not recorded"
                if drift := shipped_drift(scene, agent):
                    learnt += f" ({drift})"
                lines.append(f"| {agent} | {scene} | {learnt} | {runs} | {steps} | {wall} | {episodes} |")
            else:
                lines.append(f"| {agent} | {scene} | - | none (no training) | - | - | {episodes} |")
    return lines


def made_for(agent: str, scene: str) -> bool:
    """Whether ``agent`` can be shipped for ``scene``: every agent but one acting through an averaged actor
    (``AgentInfo.play``) on a scene whose recipe for it keeps none (``actor_average``)."""
    if AGENT_INFO.get(agent) is None or AGENT_INFO[agent].play != "averaged-select":
        return True
    name = recipe_name(agent, scene)
    if name not in recipe_names():
        return False
    recipe = load_recipe(name)
    algo = training_algo(agent)
    return recipe.config(algo, recipe.seeds(algo)[0]).actor_average > 0


def shipped_regime(scene: str, agent: str) -> str | None:
    """The training regime recorded in the shipped actor file of ``agent`` on ``scene`` (None if not recorded)."""
    path = TRAINED_DIR / f"{scene}_{agent}.npz"
    return actor_regime(load_actor(path).meta) if path.exists() else None


REWARD_ALGOS = ("mddpg", "ddpg", "dqn", "a2c")
"""The training algorithms of the reward-alone recipes, in the paper's ranking (best first)."""


@functools.cache
def regime_agents(scene: str, regime: str) -> tuple[str, dict[str, str]] | None:
    """The recipe of ``scene`` whose MDDPG trains in ``regime`` and the learned agents that recipe trains,
    ``(recipe, {algo: agent})``, read from the agent registry (``deck_sim.agents``: each learned agent's recipe on
    the scene, ``recipe_name``) and the recipes themselves (the regime of their MDDPG config, ``config_regime``).
    None if no registered MDDPG agent of ``scene`` trains in ``regime``."""
    names = set(recipe_names())
    found = []
    for agent in LEARNED:
        name = recipe_name(agent, scene)
        if training_algo(agent) != "mddpg" or name not in names or AGENT_INFO[agent].play:
            continue
        recipe = load_recipe(name)
        if config_regime(recipe.config("mddpg", recipe.seeds("mddpg")[0]).to_dict()) == regime:
            found.append(name)
    if not found:
        return None
    if len(found) > 1:
        raise ValueError(f"{scene}: recipes {', '.join(found)} all train MDDPG in regime {regime}")
    return found[0], {training_algo(agent): agent for agent in LEARNED
                      if recipe_name(agent, scene) == found[0] and not AGENT_INFO[agent].play}


def play_agent(scene: str, regime: str, algo: str, play: str) -> str | None:
    """The learned agent that ships the runs of ``algo`` of ``scene``'s recipe of ``regime`` acting in ``play``
    (``training.final_fit.PLAYS``; ``regime_agents``'s agent for ``shipped``), None if none does."""
    if (found := regime_agents(scene, regime)) is None:
        return None
    if play == "shipped":
        return found[1].get(algo)
    return next((a for a in LEARNED if recipe_name(a, scene) == found[0] and training_algo(a) == algo
                 and AGENT_INFO[a].play == play), None)


def regime_recipe(scene: str, regime: str) -> str:
    """The name of ``scene``'s recipe of ``regime`` (``regime_agents``); ValueError if it has none."""
    if (found := regime_agents(scene, regime)) is None:
        raise ValueError(f"{scene} has no recipe of regime {regime}")
    return found[0]


def recipe_seeds(scene: str, regime: str) -> dict[str, tuple[int, ...]]:
    """The training seeds of each algorithm of ``scene``'s recipe of ``regime`` (``regime_agents``); empty where the
    scene has no such recipe."""
    if (found := regime_agents(scene, regime)) is None:
        return {}
    recipe = load_recipe(found[0])
    return {algo: recipe.seeds(algo) for algo in recipe.algos}


class OffRecipe(NamedTuple):
    """A run trained with another configuration than its recipe gives now (``off_recipe_runs``)."""

    seed: int
    folder: Path
    fields: list[str]
    """The config fields that differ."""
    run_folder: bool
    """A run folder of ``--runs`` (True) or the logs shipped beside an actor (False)."""


def _seed_folders(scene: str, regime: str, runs_dir: Path, algos: tuple[str, ...] | None = None,
                  play: str = "shipped") -> list[tuple[str, int, list[tuple[Path, bool]]]]:
    """For each algorithm (``algos`` of it, default all) and seed of ``scene``'s recipe of ``regime``, the folders
    that may hold its run, in the order they are read, each with whether it is a run folder: the run folder
    ``<runs_dir>/<recipe>-<algo>-seed<k>`` (True), then the logs shipped beside the regime's actor acting in
    ``play`` (``play_agent``; ``deck_sim.policies.shipped_logs``; False), those with a ``config.json``."""
    if (found := regime_agents(scene, regime)) is None:
        return []
    recipe = load_recipe(found[0])
    out = []
    for algo in recipe.algos:
        if algos is not None and algo not in algos:
            continue
        agent = play_agent(scene, regime, algo, play)
        shipped = ({seed: folder for folder, seed in shipped_logs(agent, scene) if seed is not None}
                   if agent is not None else {})
        for seed in recipe.seeds(algo):
            folders = [(runs_dir / f"{recipe.name}-{algo}-seed{seed}", True), (shipped.get(seed), False)]
            out.append((algo, seed, [(f, own) for f, own in folders if f is not None and (f / "config.json").exists()]))
    return out


def _off_recipe(folder: Path, recipe_name_: str, algo: str, seed: int) -> list[str]:
    """The fields in which the run in ``folder`` was trained otherwise than the recipe gives ``algo`` and ``seed``
    now (``training.recipes.config_differences``; the notes a run stores do not count); empty if it is the
    recipe's run."""
    return config_differences(folder, load_recipe(recipe_name_).run(algo, seed))


def regime_runs(scene: str, regime: str, runs_dir: Path, episodes: int, workers: int | None,
                algos: tuple[str, ...] | None = None, play: str = "shipped") -> dict[str, list[dict]]:
    """Every run of ``scene``'s recipe of ``regime`` (``regime_agents``; ``algos`` of it, default all) trained with
    the configuration the recipe gives it now, each seed's actor on ``episodes`` held-out episodes
    (``training.heldout``; cached in the run folder ``<runs_dir>/<recipe>-<algo>-seed<k>``, else read from the logs
    ``scripts/train_shipped.py`` ships beside the regime's actor). A run trained with another configuration (the
    recipe changed since) is not counted (``off_recipe_runs`` names it). ``{algo: [record per seed]}``, each
    record with ``seed``, ``steps`` (trained so far), ``finished`` and ``wall_s`` (training) added; empty if the
    scene has no such recipe or no run. ``play`` (``training.final_fit.PLAYS``): how each run acts, its shipped
    actor or, with ``averaged-select``, its averaged actor choosing by its own critic (a finished run that keeps
    one; others are left out)."""
    from training.heldout import HeldOutError, held_out, shipped_held_out

    out: dict[str, list[dict]] = {}
    for algo, seed, folders in _seed_folders(scene, regime, runs_dir, algos, play):
        record = run = None
        for folder, own in folders:
            if _off_recipe(folder, regime_recipe(scene, regime), algo, seed):
                continue
            if own:
                try:
                    record = held_out(folder, episodes, workers, per_episode=True, play=play)
                except HeldOutError:
                    continue
            else:
                record = shipped_held_out(folder, episodes, play)
            if record is not None and (folder / "eval.csv").exists():
                run = folder
                break
        if run is None:
            continue
        with open(run / "eval.csv", newline="") as f:
            rows = list(csv.DictReader(f))
        config = json.loads((run / "config.json").read_text())
        total = int(config.get("total_steps") or config.get("steps") or 0)
        steps = int(float(rows[-1]["step"])) if rows else 0
        out.setdefault(algo, []).append(
            {**record, "seed": seed, "steps": steps, "finished": steps >= total,
             "wall_s": float(rows[-1]["wall_s"]) if rows else float("nan")}
        )
    return out


def off_recipe_runs(scene: str, regime: str, runs_dir: Path, counted: dict[str, list[dict]],
                    algos: tuple[str, ...] | None = None) -> dict[str, list[OffRecipe]]:
    """The runs of ``scene``'s recipe of ``regime`` that ``regime_runs`` leaves out because they were trained with
    another configuration than the recipe gives now: for each seed not in ``counted`` (``regime_runs``'s records),
    its first folder (``_seed_folders``) whose ``config.json`` differs, with the fields that differ and whether it
    is a run folder (else shipped logs). ``{algo: [OffRecipe]}``; reading configs only (nothing is evaluated)."""
    out: dict[str, list[OffRecipe]] = {}
    for algo, seed, folders in _seed_folders(scene, regime, runs_dir, algos):
        if seed in {r["seed"] for r in counted.get(algo, [])}:
            continue
        for folder, own in folders:
            if differ := _off_recipe(folder, regime_recipe(scene, regime), algo, seed):
                out.setdefault(algo, []).append(OffRecipe(seed, folder, differ, own))
                break
    return out


def reward_runs(scene: str, runs_dir: Path, episodes: int, workers: int | None) -> dict[str, list[dict]]:
    """Every run of ``scene``'s reward-alone recipe (``training/recipes/<scene>-reward.toml``), as
    ``regime_runs``."""
    return regime_runs(scene, "reward", runs_dir, episodes, workers)


def _interval(values: list[float], scale: float = 100.0, spec: str = ".1f") -> str:
    """Mean over seeds, with its Student-t 95 % interval over seeds when there are several. A seed without a value
    (path and turning of a run with no successful episode) is left out, and named; "-" when no seed has one."""
    have = [v for v in values if not np.isnan(v)]
    if not have:
        return "-"
    m, lo, hi = mean_interval(have)
    if len(have) < 2:
        text = f"{scale * m:{spec}} (one seed)"
    else:
        lo, hi = (max(0.0, lo), min(1.0, hi)) if scale == 100.0 else (lo, hi)
        text = f"{scale * m:{spec}} ({scale * lo:{spec}} to {scale * hi:{spec}})"
    missing = len(values) - len(have)
    return text + (f", {missing} seed{'s' if missing > 1 else ''} without a success left out" if missing else "")


def reward_section(reward: dict[str, dict[str, list[dict]]], recipe_steps: dict[str, int], episodes: int,
                   scenes: list[str], off: dict[str, dict[str, list[OffRecipe]]] | None = None,
                   selecting: dict[str, dict[str, list[dict]]] | None = None) -> list[str]:
    """The paper's comparison: the agents of the reward-alone recipes, each seed on the held-out episodes, mean over
    seeds with its 95 % interval over seeds, beside the paper's Tables 1-3; the prediction ablation paired by seed;
    for each of ``scenes`` with a reward-alone recipe, a line naming its agents without any run (``lacking_lines``),
    all of them where the scene has no run at all, and one naming its runs left out as trained with another
    configuration than the recipe gives now (``off``: ``{scene: off_recipe_runs}``); then the same MDDPG and DDPG
    runs acting through their own critics (``selecting``: ``{scene: regime_runs(..., play="averaged-select")}``,
    ``selecting_section``)."""
    return [
        "The paper's protocol: reinforcement learning from the reward alone (no demonstrations, no planner labels, no "
        "cloning, no final fit), `training/recipes/<scene>-reward.toml`, one run per training seed, at most "
        f"1,000,000 environment steps. Each run's actor (its best evaluation on the seed-500 stream) on the "
        f"{episodes} held-out episodes of the tables below (`training.heldout`; `python benchmarks/learning.py "
        "--recipe <scene>-reward` trains the runs and prints the same figures). Means over seeds with their "
        "Student-t 95 % interval over seeds; path and turning over successful episodes.",
        "",
        *(seed_table(reward, recipe_steps, paper=True,
                     seeds_of={scene: recipe_seeds(scene, "reward") for scene in reward}) if reward else []),
        *[line for scene in scenes if regime_agents(scene, "reward") is not None
          for line in lacking_lines(scene, "reward", reward.get(scene, {}), tuple(recipe_seeds(scene, "reward")),
                                    episodes, (off or {}).get(scene))],
        *([] if selecting is None else ["", *selecting_section(selecting, recipe_steps, episodes, scenes, {
            scene: {algo: {r["seed"]: r["steps"] for r in recs if not r["finished"]} for algo, recs in runs.items()}
            for scene, runs in reward.items()})]),
    ]


def keeps_average(scene: str) -> bool:
    """Whether ``scene``'s reward-alone recipe keeps the slow average of MDDPG's actor (``actor_average``), which
    play ``averaged-select`` needs."""
    recipe = load_recipe(regime_recipe(scene, "reward"))
    return recipe.config("mddpg", recipe.seeds("mddpg")[0]).actor_average > 0


def selecting_section(selecting: dict[str, dict[str, list[dict]]], recipe_steps: dict[str, int], episodes: int,
                      scenes: list[str], training: dict[str, dict[str, dict[int, int]]] | None = None) -> list[str]:
    """The reward-alone MDDPG and DDPG runs of ``selecting`` (``{scene: {algo: records}}`` of ``regime_runs`` with
    play ``averaged-select``) as the reward section's table gives them, each acting through its averaged actor and
    its own critic's choice; a line for each of ``scenes`` whose recipe keeps no averaged actor, or whose runs have
    none yet. ``training`` (``{scene: {algo: {seed: steps so far}}}``): the seeds still training, named as such
    (their averaged actor comes when they finish)."""
    from training.final_fit import SELECT_CANDIDATES, SELECT_SPREAD

    lines = [
        "### The same runs, acting through their own critics",
        "",
        "Each MDDPG and DDPG run of a recipe that keeps the slow average of its actor (`actor_average`) acts here "
        "through it: the averaged actor (`actor_avg.npz`, as the run ended) proposes an action, and the run's own "
        f"critic chooses among it and {SELECT_CANDIDATES} fixed candidates around it ({SELECT_SPREAD} action units; "
        "play `averaged-select` of `training.final_fit.PLAYS`). Both networks learnt from the run's reward alone. "
        "This way of acting was chosen on other episodes (the seed-2000 stream of "
        "[benchmarks.md](benchmarks.md#critic_selectpy)); the figures are the same held-out episodes as above.",
        "",
    ]
    if selecting:
        lines += seed_table(selecting, recipe_steps, paper=True,
                            seeds_of={scene: {a: k for a, k in recipe_seeds(scene, "reward").items()
                                              if a in ("mddpg", "ddpg")} for scene in selecting},
                            pending=training)
    for scene in scenes:
        if regime_agents(scene, "reward") is None or scene in selecting:
            continue
        lines.append(f"- {scene}: " + ("no finished run with an averaged actor in this checkout: `python "
                                       f"benchmarks/learning.py --recipe {regime_recipe(scene, 'reward')} --arms "
                                       "mddpg,ddpg` trains them." if keeps_average(scene) else
                                       f"`{regime_recipe(scene, 'reward')}` keeps no averaged actor "
                                       "(`actor_average`), so its runs act only as above."))
    return lines


def regime_section(found: dict[str, dict[str, dict[str, list[dict]]]], recipe_steps: dict[str, dict[str, int]],
                   episodes: int, scenes: list[str],
                   off: dict[str, dict[str, dict[str, list[OffRecipe]]]] | None = None,
                   ) -> list[str]:
    """The prediction ablation in the regimes that learn from a planner (``found``: ``{regime: {scene: runs}}`` of
    ``regime_runs``): MDDPG and DDPG seed by seed on the held-out episodes, as in the reward section but without the
    paper's columns (the paper learnt from the reward alone); the command that trains a missing regime, and the
    runs left out as trained with another configuration than the recipe gives now (``off``: ``{regime: {scene:
    off_recipe_runs}}``)."""
    lines = [
        "MDDPG against DDPG in the regimes that also learn from a planner: `planner` (`training/recipes/"
        "<scene>-planner.toml`, taught by the scripted planner on the agent's own observation) and `oracle-teacher` "
        "(`training/recipes/<scene>.toml`, taught by the full-knowledge planner). Each run's actor on the same "
        f"{episodes} held-out episodes, means over seeds with their Student-t 95 % interval over seeds (run folders "
        "of `python benchmarks/learning.py --recipe <recipe>`, or the logs shipped beside the regime's actor).",
        "",
    ]
    for regime, by_scene in found.items():
        with_recipe = {s: of_scene for s in scenes if (of_scene := regime_agents(s, regime)) is not None}
        if not with_recipe:  # (the square has no planner recipe)
            continue
        lines.append(f"### {regime}")
        lines.append("")
        if by_scene:
            lines += seed_table(by_scene, recipe_steps[regime], paper=False,
                                seeds_of={scene: recipe_seeds(scene, regime) for scene in by_scene})
        for scene in with_recipe:
            lines += lacking_lines(scene, regime, by_scene.get(scene, {}), ("mddpg", "ddpg"), episodes,
                                   (off or {}).get(regime, {}).get(scene))
        lines.append("")
    return lines


def _shown(path: Path) -> str:
    """``path`` as the docs show it: relative to the repository where it lies inside it."""
    return str(path.relative_to(ROOT) if path.is_absolute() and path.is_relative_to(ROOT) else path)


def lacking_lines(scene: str, regime: str, found: dict[str, list[dict]], algos: tuple[str, ...],
                  episodes: int, off: dict[str, list[OffRecipe]] | None = None) -> list[str]:
    """Lines naming the ``algos`` of ``scene``'s recipe of ``regime`` that have no run in ``found`` (``{algo:
    records}``), with the command that measures them: ``train_shipped.py`` where each is shipped, else
    ``learning.py``; first a line naming the runs left out as trained with another configuration than the recipe
    gives now (``off``, ``off_recipe_runs``) with the command that trains them as it is. Empty if nothing lacks."""
    recipe, by_algo = regime_agents(scene, regime)
    off = {a: seeds for a, seeds in (off or {}).items() if a in algos}
    lines = []
    if off:
        each, move = [], []
        for algo, seeds in off.items():
            fields = sorted({f for run in seeds for f in run.fields})
            where = sorted({_shown(run.folder.parent) if run.run_folder else
                            _shown(shipped_log_dir(by_algo.get(algo, algo), scene)) for run in seeds})
            move += [f"`{_shown(run.folder)}`" for run in seeds if run.run_folder]
            each.append(f"{algo} seed{'s' if len(seeds) > 1 else ''} {', '.join(str(run.seed) for run in seeds)} "
                        f"(other {', '.join(fields)}; in {', '.join(f'`{w}`' for w in where)})")
        if all(a in by_algo for a in off):
            how = (f"`python scripts/train_shipped.py --scenes {scene} --algos {','.join(by_algo[a] for a in off)} "
                   "--redo` trains them with the recipe as it is")
        else:
            how = f"`python benchmarks/learning.py --recipe {recipe} --arms {','.join(off)}` trains them"
        if move:
            how += f" once {', '.join(move)} {'is' if len(move) == 1 else 'are'} moved away"
        lines.append(f"- {scene}: left out, trained with another configuration than `{recipe}` gives now (each "
                     f"run's `config.json` says what it was trained with): {'; '.join(each)}. {how}.")
    lacking = [a for a in algos if a not in found and a not in off]
    if not lacking:
        return lines
    agents = ",".join(by_algo.get(a, a) for a in lacking)
    if all(a in by_algo and (TRAINED_DIR / f"{scene}_{by_algo[a]}.npz").exists() for a in lacking):
        how = (f"`python scripts/train_shipped.py --scenes {scene} --algos {agents} --redo --episodes-per-run "
               f"{episodes}` measures each seed of the shipped file (and the shipped agent again)")
    else:
        how = f"`python benchmarks/learning.py --recipe {recipe} --arms {','.join(lacking)}` trains them"
    return [*lines, f"- {scene}: no run of `{recipe}` ({', '.join(lacking)}) with a held-out record of {episodes} "
            f"episodes in this checkout: {how}."]


def seed_table(runs: dict[str, dict[str, list[dict]]], recipe_steps: dict[str, int], paper: bool,
               seeds_of: dict[str, dict[str, tuple[int, ...]]] | None = None,
               pending: dict[str, dict[str, dict[int, int]]] | None = None) -> list[str]:
    """One row per scene and algorithm of ``runs`` (``{scene: {algo: [record per seed]}}``): seeds, steps, training
    time, held-out success (mean with its 95 % interval over seeds, and each seed's), collisions, path and turning,
    over the seeds that finished their recipe's budget (every seed while none has; the others are named, as are
    the recipe's seeds of ``seeds_of`` (``{scene: {algo: seeds}}``, ``recipe_seeds``) that have no record, those of
    ``pending`` (``{scene: {algo: {seed: steps so far}}}``) as still training);
    with ``paper``, the paper's success and turning beside them. Then the paired comparisons (``ablation_lines``,
    which name the paper's direction only with ``paper``)."""
    lines = [
        "| scene | agent | seeds (steps each) | training time (all seeds) | success % | each seed | "
        + ("paper % | " if paper else "") + "collision % | path / shortest | turning deg |"
        + (" paper turning deg |" if paper else ""),
        "|---|---|---|---:|---:|---|" + ("---:|" if paper else "") + "---:|---:|---:|" + ("---:|" if paper else ""),
    ]
    notes = []
    for scene, algos in runs.items():
        for algo, every in algos.items():
            # a seed still training is named, and left out of the figures while another seed has finished
            recs = [r for r in every if r["finished"]] or every
            training = [r for r in every if not r["finished"]]
            steps = sorted({r["steps"] for r in recs})
            seeds = f"{len(recs)}: {', '.join(str(r['seed']) for r in recs)} ({'/'.join(f'{s:,}' for s in steps)}"
            if len(recs) < len(every):
                seeds += "); " + ", ".join(f"seed {r['seed']} still training (last evaluated at {r['steps']:,} of "
                                            f"{recipe_steps[scene]:,} steps), left out" for r in training)
            else:
                seeds += f"{'' if not training else f'; of {recipe_steps[scene]:,}, still training'})"
            absent = [k for k in (seeds_of or {}).get(scene, {}).get(algo, ()) if k not in {r["seed"] for r in every}]
            going = (pending or {}).get(scene, {}).get(algo, {})
            for k in [k for k in absent if k in going]:  # (a way of acting its run gets only when it finishes)
                seeds += (f"; seed {k} still training (last evaluated at {going[k]:,} of {recipe_steps[scene]:,} "
                          "steps), left out")
            absent = [k for k in absent if k not in going]
            if absent:
                seeds += (f"; seed{'s' if len(absent) > 1 else ''} {', '.join(map(str, absent))} with no held-out "
                          "record of the recipe as it is in this checkout (not trained here, stopped before its "
                          "first evaluation, unreadable, or trained with another configuration), left out")
            each = ", ".join(f"{100 * r['success']:.0f}" for r in recs)
            row = (f"| {scene} | {algo} | {seeds} | {sum(r['wall_s'] for r in recs) / 60:.0f} min | "
                   f"{_interval([r['success'] for r in recs])} | {each} | ")
            if paper:
                p = PAPER["success"].get(scene, {}).get(algo)
                row += f"{'-' if p is None else f'{100 * p:.0f}'} | "
            row += (f"{_interval([r['collision'] for r in recs])} | "
                    f"{_interval([r['path_ratio'] for r in recs], 1.0, '.3f')} | "
                    f"{_interval([r['turning_deg'] for r in recs], 1.0, '.0f')} |")
            if paper:
                p = PAPER["turning_deg"].get(scene, {}).get(algo)
                row += f" {'-' if p is None else f'{p:.0f}'} |"
            lines.append(row)
        notes += ablation_lines(scene, algos, paper)
    return [*lines, "", *notes]


def ablation_lines(scene: str, algos: dict[str, list[dict]], paper: bool = True) -> list[str]:
    """MDDPG against DDPG (the prediction ablation) and each neighbour of the paper's ranking: the difference of
    held-out success paired by seed, with its 95 % interval over seeds and, where the records keep each episode's
    success, the bootstrap interval over seeds and episodes (``paired_bootstrap_interval``); "ahead" or
    "behind" only when every interval given excludes zero (seeds whose differences are all equal give no interval
    over seeds, and are said to); and which of MDDPG and DDPG turns more and drives
    further ("as much as", "as long as" where the means are equal at the printed precision; no line where a seed
    has no successful episode to average), against the paper's direction. Only runs that finished their recipe's
    budget are compared (equal budgets); a seed still training is named as left out."""
    out = []
    ranked = [a for a in REWARD_ALGOS if a in algos]
    for a, b in zip(ranked, ranked[1:], strict=False):
        ra, rb = ({r["seed"]: r for r in algos[x]} for x in (a, b))
        shared = sorted(set(ra) & set(rb))
        both = [s for s in shared if ra[s]["finished"] and rb[s]["finished"]]  # (at the recipe's whole budget)
        training = [s for s in shared if s not in both]
        left_out = (f" (seed{'s' if len(training) > 1 else ''} {', '.join(map(str, training))} still training: "
                    "left out)") if training else ""
        if not both:
            if training:
                out.append(f"- {scene}: {a} - {b}: no seed finished for both yet{left_out}.")
            continue
        diff = [ra[s]["success"] - rb[s]["success"] for s in both]
        m, lo, hi = mean_interval(diff)
        intervals = [(lo, hi, "over seeds")] if len(both) > 1 else []
        if all("goal_each" in r[s] for r in (ra, rb) for s in both):
            _, blo, bhi = paired_bootstrap_interval(np.array([ra[s]["goal_each"] for s in both]),
                                                    np.array([rb[s]["goal_each"] for s in both]))
            intervals.append((blo, bhi, f"over {'seeds and ' if len(both) > 1 else ''}episodes, paired by episode"))
        # (seeds that differ by exactly the same points give an interval of no width: said as such, not as one)
        real = [i for i in intervals if not (i[2] == "over seeds" and i[1] - i[0] < 1e-9)]  # (float rounding)
        spread = "; ".join([*(f"every seed {100 * x:+.1f} points, no spread over seeds to give an interval"
                              for x, y, how in intervals if (x, y, how) not in real),
                            *(["95 % interval " + "; ".join(f"{100 * x:+.1f} to {100 * y:+.1f} points {how}"
                                                            for x, y, how in real)] if real else [])])
        if len(both) > 1 and real:
            verdict = f"{a} " + ("ahead" if all(x[0] > 0 for x in real) else
                                 "behind" if all(x[1] < 0 for x in real) else "not separated") + f" ({spread})"
        elif len(both) > 1:
            verdict = f"no verdict ({spread})"
        else:  # (one seed's episodes say nothing of the spread between training seeds)
            verdict = "one seed, no verdict" + (f" ({spread})" if intervals else "")
        ranks = f"; the paper ranks {a} above {b}" if paper else ""
        over = f"seed{'s' if len(both) > 1 else ''} {', '.join(map(str, both))}"
        out.append(f"- {scene}: {a} - {b}, success paired over {over}{left_out}: {100 * m:+.1f} points, "
                   f"{verdict}{ranks}.")
    done = {a: [r for r in algos.get(a, []) if r["finished"]] for a in ("mddpg", "ddpg")}
    if done["mddpg"] and done["ddpg"]:
        for key, paper_key, more, less, same, what, unit, paper_unit in (
            ("turning_deg", "turning_deg", "more than", "less than", "as much as", " turns {} DDPG",
             "deg per successful episode", "deg"),
            ("path_ratio", "path_length", "longer than", "shorter than", "as long as", "'s paths are {} DDPG's",
             "of the shortest", "Unity units"),
        ):
            m, d = (float(np.mean([r[key] for r in done[a]])) for a in ("mddpg", "ddpg"))
            if not (np.isfinite(m) and np.isfinite(d)):  # (over successful episodes: a seed without any has none)
                continue
            pm, pd = (PAPER[paper_key].get(scene, {}).get(a) for a in ("mddpg", "ddpg"))
            theirs = "" if pm is None or not paper else \
                f"; the paper's MDDPG {(more if pm > pd else less).split()[0]} ({pm:.2f} against {pd:.2f} {paper_unit})"
            spec = ".0f" if key == "turning_deg" else ".3f"
            # equal at the printed precision: "more" or "less" would contradict the figures beside it
            how = same if f"{m:{spec}}" == f"{d:{spec}}" else more if m > d else less
            out.append(f"- {scene}: MDDPG{what.format(how)} ({m:{spec}} against {d:{spec}} {unit}, "
                       f"means over the finished seeds){theirs}.")
    return out


def targets(res, reward: dict[str, dict[str, list[dict]]],  # noqa: ANN001 - EvalResults
            scenes: tuple[str, ...] = ("deck1", "deck2", "square"),
            selecting: dict[str, dict[str, list[dict]]] | None = None) -> list[str]:
    """The paper's MDDPG figures and the targets of the reward regime (90 % on deck 1, 80 % on deck 2), checked
    against the reward-alone runs (the paper's protocol) of ``scenes``, and against the same runs acting through
    their own critics where ``selecting`` has them (``selecting_section``); the square, which the paper does not
    report, with its figure and no target; then the shipped MDDPG, which names its regime."""
    out = []
    for scene, goal in (("deck1", 0.90), ("deck2", 0.80), ("square", None)):
        if scene not in scenes:
            continue
        paper = PAPER["success"].get(scene, {}).get("mddpg")
        against = (f"target {100 * goal:.0f} %, the paper {100 * paper:.0f} %" if goal is not None else
                   "no target: the paper reports the decks only")
        for found, how in ((reward, ""), (selecting or {}, ", acting through its critic")):
            recs = found.get(scene, {}).get("mddpg")
            what = f"MDDPG from the reward alone on {scene}{how}"
            if not recs:
                if not how:  # (the runs acting through their critics are named in their own section)
                    out.append(f"- {what}: no run yet ({against}).")
                continue
            finished = [r for r in recs if r["finished"]]
            counts = f"{len(recs)} seed(s), {len(finished)} finished"
            undecided = f"not decided: {counts}; at least 3 finished needed"
            if not finished:
                out.append(f"- {what}: no seed finished yet ({against}): "
                           f"{undecided if goal is not None else counts}.")
                continue
            m = float(np.mean([r["success"] for r in finished]))  # (a run still training is not at the budget)
            if len(finished) == len(recs) and len(recs) >= 3:
                verdict, which = ("met" if goal is not None and m >= goal else "not met"), f"{len(recs)} seed(s)"
            else:
                verdict, which = undecided, f"the {len(finished)} finished seed(s) of {len(recs)}"
            if goal is None:
                out.append(f"- {what}: {100 * m:.1f} % (mean of {which}; {against}).")
            else:
                out.append(f"- {what}: {100 * m:.1f} % (mean of {which}) against the target of {100 * goal:.0f} % "
                           f"and the paper's {100 * paper:.0f} %: {verdict}.")
    for scene in ("deck1", "deck2"):
        try:
            m = res.summary(scene, "mddpg")
        except KeyError:
            continue
        regime = shipped_regime(scene, "mddpg")
        out.append(f"- The shipped MDDPG on {scene} (learnt from {regime_text(regime)}): {100 * m['goal_rate']:.1f} % "
                   f"on the tables' episodes; the paper's {100 * PAPER['success'][scene]['mddpg']:.0f} % is from the "
                   "reward alone, so only the lines above compare with it.")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--agents", default=AGENTS)
    parser.add_argument("--scenes", default="deck1,deck2,square")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--workers", type=int, default=None, help="process-pool workers (default: CPU count)")
    parser.add_argument("--out", default="runs/results", help="folder for the full report and the episode logs")
    parser.add_argument("--runs", default="runs/learning", help="training run folders (learning curves)")
    parser.add_argument("--doc", default=str(ROOT / "docs" / "results.md"))
    parser.add_argument(
        "--reuse",
        action="store_true",
        help="reuse a scene's report in --out/<scene> when the code, scene files, policy files and settings are the "
        "same (evaluate scenes as their policies are shipped, then write the page)",
    )
    args = parser.parse_args()
    agents = [a for a in args.agents.split(",") if a]
    scenes = [s for s in args.scenes.split(",") if s]
    missing = {}  # scene -> learned agents with no shipped policy for it (reported, not evaluated)
    plan = {}
    for scene in scenes:
        missing[scene] = [a for a in agents if a in LEARNED and not (TRAINED_DIR / f"{scene}_{a}.npz").exists()]
        plan[scene] = tuple(a for a in agents if a not in missing[scene])
    commit = git_commit()
    started = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    bar = progress(total=args.episodes * sum(len(a) for a in plan.values()), unit="ep", desc="results")
    parts = []
    reused: list[str] = []  # scenes whose evaluation came from --out (run before, maybe on a busy machine)
    with bar:
        for scene in scenes:
            cfg = EvalConfig(
                agents=plan[scene], scenes=(scene,), episodes=args.episodes, workers=args.workers, out=args.out
            )
            cache = Path(args.out) / scene
            key = fingerprint(cfg)
            if args.reuse and (cached := load_scene_report(cache, cfg, key)) is not None:
                print(f"{scene}: reusing {cache} (same code, scenes, policies and settings)", file=sys.stderr)
                bar.update(args.episodes * len(plan[scene]))
                parts.append(cached)
                reused.append(scene)
                continue
            base = bar.n
            part = evaluate(cfg, progress=lambda done, total, batch, base=base: bar.update(base + done - bar.n))
            write_report(part, cache)
            (cache / "fingerprint.json").write_text(json.dumps({"key": key, "logs": part.logs, "wall_s": part.wall_s}))
            parts.append(part)
    res = EvalResults.merge(parts)
    cfg = res.config
    reward, reward_off = {}, {}
    for scene in scenes:
        print(f"{scene}: the reward-alone runs on held-out episodes", file=sys.stderr)
        if found := reward_runs(scene, Path(args.runs), args.episodes, args.workers):
            reward[scene] = found
        if regime_agents(scene, "reward") is not None:
            reward_off[scene] = off_recipe_runs(scene, "reward", Path(args.runs), found)
    recipe_steps = {scene: load_recipe(regime_recipe(scene, "reward")).steps("mddpg") for scene in reward}
    selecting = {}  # the same MDDPG and DDPG runs, each acting through its averaged actor and its own critic
    for scene in reward:
        if keeps_average(scene):
            print(f"{scene}: the reward-alone runs acting through their critics on held-out episodes", file=sys.stderr)
            if found := regime_runs(scene, "reward", Path(args.runs), args.episodes, args.workers, ("mddpg", "ddpg"),
                                    play="averaged-select"):
                selecting[scene] = found
    other_regimes: dict[str, dict[str, dict[str, list[dict]]]] = {}
    other_off: dict[str, dict[str, dict[str, list[OffRecipe]]]] = {}
    for regime in (r for r in REGIMES if r != "reward"):  # (the reward regime has its own section)
        other_regimes[regime], other_off[regime] = {}, {}
        for scene in scenes:
            if regime_agents(scene, regime) is None:
                continue
            print(f"{scene}: the {regime} runs on held-out episodes", file=sys.stderr)
            if found := regime_runs(scene, regime, Path(args.runs), args.episodes, args.workers, ("mddpg", "ddpg")):
                other_regimes[regime][scene] = found
            other_off[regime][scene] = off_recipe_runs(scene, regime, Path(args.runs), found, ("mddpg", "ddpg"))
    other_steps = {regime: {scene: load_recipe(regime_recipe(scene, regime)).steps("mddpg") for scene in by_scene}
                   for regime, by_scene in other_regimes.items()}
    write_report(res, args.out)
    figures = Path(args.doc).parent / "results"
    figures.mkdir(parents=True, exist_ok=True)
    curve_lines = []
    for scene in scenes:
        runs = {}
        for agent in agents:
            if agent in LEARNED and not AGENT_INFO[agent].play:  # (another way of acting: the same runs' curves)
                # scripts/train_shipped.py's run folder
                run = Path(args.runs) / f"{recipe_name(agent, scene)}-{training_algo(agent)}-seed0"
                # the log shipped with the actor (the run folder may hold a newer, unshipped run), else the run's
                for folder in (shipped_log_dir(agent, scene), run):
                    if (folder / "eval.csv").exists():
                        runs[agent] = folder
                        break
        if runs:
            png = plot_learning_curves(runs, figures / f"learning_{scene}.png", title=f"{scene}: average reward")
            curve_lines.append(f"![learning curves, {scene}](results/{png.name})")
            how = []
            for agent, run in runs.items():
                cfg_path = run / "config.json"
                c = json.loads(cfg_path.read_text()) if cfg_path.exists() else {}
                with open(run / "eval.csv") as f:
                    episodes = sorted({r["episodes"] for r in csv.DictReader(f)})
                stream = f"the seed-{c['eval_seed']} stream" if "eval_seed" in c else "its trainer's evaluation stream"
                others = sorted(d.name for d in run.glob("seed*") if (d / "eval.csv").exists())
                kin = ("the seeds it was chosen from" if AGENT_INFO[agent].trainer == "sb3"
                       else "the shipped ensemble's other runs")
                also = (f" (seed {c.get('seed', 0)}'s run; {kin}: "
                        f"{', '.join(f'`{o}/eval.csv`' for o in others)})") if others else ""
                how.append(f"{agent}: `{_shown(run)}/eval.csv`{also}, {'/'.join(episodes)} episodes of {stream} "
                           "per point")
            curve_lines.append(
                f"*{scene}: held-out average reward and success against training steps ({'; '.join(how)}).*"
            )
            curve_lines.append("")
        elif (figures / f"learning_{scene}.png").exists():  # logs gone (run folders are not committed): keep it
            curve_lines.append(f"![learning curves, {scene}](results/learning_{scene}.png)")
            curve_lines.append(
                f"*{scene}: drawn by an earlier run of this script from the shipped actors' training logs, which this "
                f"checkout does not hold (`git log docs/results/learning_{scene}.png` names the commit; "
                "`scripts/train_shipped.py` now keeps each shipped run's log in `deck_sim/trained/logs/`).*"
            )
            curve_lines.append("")
    traj_lines = []
    plots = plot_trajectories(res, Path(args.out) / "trajectories")
    for scene in scenes:
        mine = [p for p in plots if p.name.startswith(f"{scene}-mddpg-")] or [
            p for p in plots if p.name.startswith(f"{scene}-")
        ]
        if mine:
            dest = figures / f"trajectory_{scene}.png"
            shutil.copyfile(mine[0], dest)
            traj_lines.append(f"![{scene} trajectory](results/{dest.name})")
            traj_lines.append(f"*{scene}: episode 0 (seed {cfg.seed}), agent {mine[0].name.split('-')[1]}.*")
            traj_lines.append("")
    doc = [
        "# Results: the task suite on physics, beside the paper",
        "",
        f"Generated by `python scripts/make_results.py --episodes {args.episodes}` on {started}, commit "
        f"`{commit}`, {machine()}; {res.wall_s / 60:.1f} min of evaluation ({cfg.backend} backend; the scenes' "
        "wall times summed" + (f", those of {', '.join(reused)} from the run that computed them" if reused else "")
        + "). Do not edit by hand: rerun the command.",
        "",
        "Agents: the learned policies shipped in `deck_sim/trained/` (trained by `scripts/train_shipped.py`): "
        "`mddpg-reward` and `ddpg-reward`, MDDPG and DDPG without prediction learnt from the reward alone as in the "
        "paper; `mddpg-reward-select` and `ddpg-reward-select`, the same runs each acting through its averaged actor "
        "and its own critic's choice (scenes whose recipe keeps an averaged actor); `mddpg-planner` and "
        "`ddpg-planner`, the same agents taught by the scripted planner on their own "
        "observation; `mddpg` and `ddpg`, taught by the full-knowledge planner (the column `learnt from` says so); "
        "`dqn-reward` and `a2c-reward`, DQN and A2C learnt from the reward alone at DDPG's budget with their own "
        "tuned fields (one run each, the seed with the best periodic evaluation); `dqn` and `a2c`, short runs at "
        "the default fields; `scripted-observed`, the planner on the observation alone (the `planner` regime's "
        "teacher); "
        "the classical references of `deck_sim/control/planners.py` "
        "(APF, A* with replanning, CasADi MPC; they plan around the MPC predictor's forecast, the one MDDPG sees) "
        "and `scripted`, the full-knowledge planner that sees the movers' true future (the solvability ceiling); "
        "`scripted-body` is the same planner checking the aircraft's nose and tail on the way its tracker will "
        "really take it (the teacher of the `body` recipes; on the square, whose walker is a disc, it is `scripted`).",
        "",
        "## The paper's comparison: learnt from the reward alone",
        "",
        *(reward_section(reward, recipe_steps, args.episodes, scenes, reward_off, selecting)
          if reward or any(reward_off.values()) else [
            "No run of a reward-alone recipe in this checkout: `python benchmarks/learning.py --recipe deck1-reward` "
            "(and `deck2-reward`, `square-reward`) trains them."]),
        "",
        "## The prediction ablation in the other regimes",
        "",
        *regime_section(other_regimes, other_steps, args.episodes, scenes, other_off),
        "## What stands behind each number",
        "",
        *provenance(scenes, agents, args.episodes, missing),
        "",
        "## Tables",
        "",
        markdown_tables(res),
        "Why MDDPG turns more than DDPG here: [benchmarks.md](benchmarks.md#turningpy) splits the turning by speed.",
        "",
        "## Targets",
        "",
        *targets(res, reward, tuple(scenes), selecting),
        "",
    ]
    if curve_lines:
        doc += ["## Learning curves", "", *curve_lines]
    if traj_lines:
        doc += ["## Trajectories", "", *traj_lines]
    doc += ["## Reproduce", "", "```", f"python scripts/make_results.py --episodes {args.episodes}"]
    doc += [
        f"deck-sim eval --agents {','.join(plan[scene])} --scenes {scene} --episodes {args.episodes}"
        for scene in scenes
    ]
    doc += [
        "```",
        f"The `deck-sim eval` lines give the same numbers (same seeds) scene by scene; the full report and the "
        f"episode logs are in `{args.out}` after the first.",
        "",
    ]
    Path(args.doc).write_text("\n".join(doc))
    print(f"wrote {args.doc} ({res.wall_s:.0f} s of evaluation)", file=sys.stderr)


if __name__ == "__main__":
    main()

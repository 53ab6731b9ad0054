"""Train the policies shipped in ``deck_sim/trained/`` and measure them on held-out episodes.

For each scene and agent (``--algos``, default every learned agent of ``deck_sim.agents``):

- ``mddpg`` and ``ddpg``: one ``training.loop.Trainer`` run of the ``[ddpg]`` table of the scene's recipe,
  ``training/recipes/<scene>.toml`` (``training.recipes``), per seed of the recipe's ``seeds`` (or ``--seeds``),
  each in ``--out/<scene>-<algo>-seed<seed>``: the run ``deck-sim train --recipe <scene> --algo <algo> --seed
  <seed>`` makes. DDPG is MDDPG without prediction (predictor ``none``), same recipe, seeds and budget. With
  several seeds the shipped file is an ensemble (``deck_sim.policies.EnsemblePolicy``): the seeds' actors acting
  by the mean of their actions.
- ``mddpg-reward`` and ``ddpg-reward``: the same with the scene's reward-alone recipe,
  ``training/recipes/<scene>-reward.toml``, in ``--out/<scene>-reward-<algo>-seed<seed>``; ``mddpg-planner`` and
  ``ddpg-planner`` with ``<scene>-planner.toml`` (taught by the planner on the agent's own observation).
  ``mddpg-reward-select`` and ``ddpg-reward-select``: the runs of ``mddpg-reward`` and ``ddpg-reward`` (the same
  folders, trained once), each acting through its averaged actor with its own critic choosing each action
  (``training.final_fit.played_actor``, play ``averaged-select``); a scene whose recipe keeps no averaged actor
  (no ``actor_average``) is refused when the agent is named in ``--algos``, skipped otherwise. They share their
  runs with ``mddpg-reward`` and ``ddpg-reward``: ship both after the runs change (``--redo`` of one leaves the
  other as it was shipped).
- ``dqn`` and ``a2c``: stable-baselines3 through ``training.baselines.train_baseline`` with the recipe's
  ``[sb3]`` table, in ``--out/<scene>-<algo>-seed<seed>``; the networks are exported to numpy
  (``training.baselines.export_sb3``), so the shipped files need neither stable-baselines3 nor ``training``.
  ``dqn-reward`` and ``a2c-reward``: the same with the reward-alone recipe's ``[sb3]`` table (DDPG's budget and
  seeds, each algorithm's tuned fields), in ``--out/<scene>-reward-<algo>-seed<seed>``. A mean of several DQN
  actors' discrete displacements is not DQN, so with several seeds a stable-baselines3 agent ships one run: the
  one whose best periodic evaluation (seed-500 episodes, the stream that already picks each run's actor) is
  highest (``best_run``); every seed's logs are shipped beside it.

MDDPG and DDPG of a scene train for the same number of environment steps; DQN and A2C for the recipe's
``[sb3]`` steps (in the reward-alone recipes, the same as MDDPG's). ``--steps`` sets one budget for every agent.

A run folder that already holds a checkpoint is resumed; one with a final ``actor.npz`` is not trained again. The
shipped actor of each run (``shipped_actor``: the final actor of a recipe that ends with the cloning fit, else the
one with the best periodic held-out evaluation on the seed-500 stream) is copied, or the runs' actors joined, to
``deck_sim/trained/<scene>_<algo>.npz`` (weights only: no buffer, no optimiser state) and measured on ``--episodes``
further held-out episodes, the stream of ``deck-sim run --scene <scene> --policy <algo> --seed 1000`` (never a
training, demonstration or selection episode). The figures go to ``deck_sim/trained/results.json``
(``{scene: {algo: figures}}``) and ``deck_sim/trained/README.md``, written by this script, never by hand, as is
the table between the ``README_MARKERS`` of the project's README; the runs' periodic evaluation logs and configs
go to ``deck_sim/trained/logs/<scene>_<algo>/`` (``ship_logs``; the learning curves of
``docs/results.md``), and the training time recorded is the sum of the runs' wall-clock times. An agent
already shipped and measured is skipped unless ``--redo`` (or ``--evaluate-only``, which measures the shipped files
again without training).

A seed of MDDPG or DDPG whose run folder is not here (no ``actor.npz``, no checkpoint) but whose actor is in the
file already shipped, trained with the recipe's configuration for that seed, is taken from that file with its
shipped logs (``shipped_members``), not trained again: a shipped agent gains seeds on a checkout that never held its
earlier runs (``--seeds 0,1,2`` after ``--seeds 0``). The notes a run stores (the name its recipe had then) are not
part of its configuration. Such a seed whose shipped logs hold no valid record of ``--episodes-per-run`` held-out
episodes is measured again from its actor in the file (``measure_kept``; ``--redo`` does it for a file that already
holds every seed). For DQN and A2C such a seed's shipped logs (trained with the
recipe's configuration) take part in the choice of the run again (``kept_logs``): the shipped file stays if it is
still the best, or a new run replaces it (a tie goes to the lower seed, as ever).

Order: agents whose runs are finished first, then by the environment steps still to train (a DDPG step counted
twice), so the files land incrementally; each is shipped as soon as it is measured. Several copies may run at once
on disjoint work (``results.json`` is updated under a file lock).

Long work: run it in the background (``nohup nice -n 10 python scripts/train_shipped.py > train.log 2>&1 &``),
never in tests.

    python scripts/train_shipped.py [--scenes deck1,deck2,square] [--algos mddpg,ddpg,dqn,a2c,mddpg-reward,...]
                                    [--steps N] [--seeds 0,1] [--episodes 200] [--redo | --evaluate-only]
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MUJOCO_GL", "disable")

import argparse  # noqa: E402
import contextlib  # noqa: E402
import csv  # noqa: E402
import fcntl  # noqa: E402
import hashlib  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import shutil  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from collections.abc import Iterator, Mapping  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import deck_sim  # noqa: E402
from deck_sim.agents import AGENTS, names, recipe_name, training_algo  # noqa: E402
from deck_sim.metrics import summarize  # noqa: E402
from deck_sim.policies import (  # noqa: E402
    SHIPPED_ALGOS,
    TRAINED_DIR,
    EnsemblePolicy,
    LearnedPolicy,
    load_actor,
    seeds_text,
    shipped_log_dir,
    shipped_logs,
)
from deck_sim.policies.regimes import config_regime  # noqa: E402
from deck_sim.rollout import run_episode  # noqa: E402
from training.checkpoints import comparable  # noqa: E402
from training.config import ConfigError, TrainConfig  # noqa: E402
from training.final_fit import AVERAGED_SELECT_FILE, play_settings, played_actor  # noqa: E402
from training.heldout import held_out as held_out_record  # noqa: E402
from training.heldout import held_out_file, shipped_held_out  # noqa: E402
from training.recipes import (  # noqa: E402
    config_differences,
    differing_fields,
    load_recipe,
    recipe_names,
    shipped_drift,
)

HELD_OUT_SEED = 1000
DDPG_ALGOS = names(trainer="ddpg")
"""The agents trained by ``training.ddpg`` (MDDPG, DDPG); the others by stable-baselines3."""


def play_of(algo: str) -> str:
    """How the runs behind the shipped ``algo`` act (``training.final_fit.PLAYS``): ``shipped`` unless the agent
    names another way (``deck_sim.agents.AgentInfo.play``)."""
    return AGENTS[algo].play or "shipped"
LABELS = {"mddpg": "MDDPG", "ddpg": "DDPG (no prediction)", "dqn": "DQN", "a2c": "A2C",
          "mddpg-reward": "MDDPG (reward alone)", "ddpg-reward": "DDPG (reward alone, no prediction)",
          "mddpg-reward-select": "MDDPG (reward alone, averaged actor choosing by its critic)",
          "ddpg-reward-select": "DDPG (reward alone, no prediction, averaged actor choosing by its critic)",
          "dqn-reward": "DQN (reward alone, tuned)", "a2c-reward": "A2C (reward alone, tuned)",
          "mddpg-planner": "MDDPG (planner on its observation)",
          "ddpg-planner": "DDPG (planner on its observation, no prediction)"}
PROJECT_README = Path(__file__).resolve().parents[1] / "README.md"
README_MARKERS = ("<!-- shipped-table: start (written by scripts/train_shipped.py) -->", "<!-- shipped-table: end -->")
"""The project README's shipped-policies table lies between these two lines; ``write_readme`` rewrites it from
``results.json`` (``tests/test_baseline_export.py`` checks the two agree)."""


def held_out(actor: Path, scene: str, episodes: int) -> dict[str, float]:
    """The actor (or ensemble) on ``episodes`` consecutive episodes of ``deck_sim.load(scene, seed=1000)``."""
    policy = load_actor(actor)
    env = deck_sim.load(scene, seed=HELD_OUT_SEED, **policy.scene_overrides)  # its predictor and observation
    return summarize([run_episode(env, policy, episode=k) for k in range(episodes)])


def ship_logs(runs: list[Path], seeds: tuple[int, ...], scene: str, algo: str, held_out_episodes: int = 100) -> Path:
    """Copy each run's held-out evaluation log (``eval.csv``), ``config.json`` and its actor's measurements on
    the first ``held_out_episodes`` of ``docs/results.md``'s episodes (``training.heldout``) to ``deck_sim/trained/logs/
    <scene>_<algo>/`` beside the shipped actor (a few KiB each), so that ``scripts/make_results.py`` draws its
    learning curve on a checkout without the run folders: the first run's in that folder, the others' (an ensemble's
    further seeds, or the seeds a stable-baselines3 agent was not chosen from) in ``seed<seed>/`` below it
    (``deck_sim.policies.shipped_logs``)."""
    logs = shipped_log_dir(algo, scene)
    for old in logs.glob("seed*"):  # nothing of an earlier shipped run may stay beside the new logs
        if old.is_symlink() or old.is_file():
            old.unlink()
        elif old.is_dir():
            shutil.rmtree(old)
    for i, (run, seed) in enumerate(zip(runs, seeds, strict=True)):
        folder = logs if i == 0 else logs / f"seed{seed}"
        # (not other counts' caches; of an agent that acts otherwise than its runs' shipped actor, that play's)
        names = ["eval.csv", "config.json", held_out_file(held_out_episodes, play_of(algo))]
        for stale in folder.glob(held_out_file("*", play_of(algo))):  # an earlier run's measurements
            stale.unlink()
        for name in names:
            (folder / name).unlink(missing_ok=True)
            if (run / name).exists():
                folder.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(run / name, folder / name)
    return logs


def file_seeds(meta: dict[str, Any]) -> tuple[int, ...]:
    """The training seeds of a shipped file, from its ``meta`` record (each member's, for an ensemble)."""
    return tuple(int(m["config"]["seed"]) for m in meta.get("members") or [meta])


def ship(runs: list[Path | LearnedPolicy], dest: Path, play: str = "shipped") -> None:
    """Write ``dest`` atomically: the one run's shipped actor (``training.loop.shipped_actor``; the actor of another
    ``play``, ``training.final_fit.played_actor``, for an agent that acts otherwise), or with several
    runs an ``EnsemblePolicy`` of their shipped actors, which must differ in their seed alone (``training_of``: a
    folder finished by another command with other ``--steps`` or fields is refused, not averaged in). An actor of
    the file shipped before (``shipped_members``) stands for a run whose folder is not here."""
    if len(runs) == 1 and isinstance(runs[0], Path):
        tmp = dest.with_name(dest.name + ".tmp")
        shutil.copyfile(played_actor(runs[0], play), tmp)
        os.replace(tmp, dest)
        return
    members = [r if isinstance(r, LearnedPolicy) else LearnedPolicy.load(played_actor(r, play)) for r in runs]
    first = training_of(members[0])
    for run, member in zip(runs[1:], members[1:], strict=True):
        differ = differing_fields(first, training_of(member))
        if differ:
            raise SystemExit(f"{dest}: the runs {runs[0]} and {run} differ in more than their seed "
                             f"({', '.join(differ)}), so they are not one recipe and budget; train them again or "
                             "remove one")
    if len(members) == 1:  # one actor of an ensemble shipped before, on its own
        members[0].save(dest)
        return
    EnsemblePolicy(members, source=str(dest)).save(dest)


def training_of(actor: LearnedPolicy) -> dict[str, Any]:
    """What trained ``actor``: its run's config with the fields added since it was made at their defaults, less the
    seed, with the scene and agent (compared by ``differing_fields``, which leaves out the notes); a config that no
    longer parses stands as saved."""
    config = dict(comparable(actor.meta["config"]))  # (as a resumed run reads it)
    config.pop("seed", None)
    return {**config, "meta_algo": actor.meta.get("algo"), "meta_scene": actor.meta.get("scene")}


def measure_kept(kept: Mapping[int, LearnedPolicy | None], staged: Mapping[int, Path], episodes: int,
                 label: str = "", play: str = "shipped") -> None:
    """Measure each kept actor (a seed taken from the shipped file) whose staged logs hold no record of
    ``episodes`` held-out episodes (``training.heldout``; a file shipped before those records were kept), so that
    its record is shipped with the logs and ``scripts/make_results.py`` compares that seed too. The actor is
    written into the staged folder for the measurement and removed after it; ``label`` (the scene and agent) starts
    the progress line. ``play``: the agent's way of acting. Its kept actors act that way already, with today's
    settings (``kept_seeds``); an ``averaged-select`` one is written as ``actor_avg.npz``, from which
    ``training.final_fit.played_actor`` makes the same selecting actor again (the file's own offsets are
    replaced by the same draws)."""
    for seed, actor in sorted(kept.items()):
        folder = staged.get(seed)
        if actor is None or folder is None or shipped_held_out(folder, episodes, play) is not None:
            continue  # (a record of other episodes, or without each episode's outcome, is measured again)
        if play == "averaged-select":
            path = folder / "actor_avg.npz"
        else:
            path = folder / ("actor.npz" if actor.meta.get("polished") else "actor_best.npz")  # (training.final_fit)
        print(f"{label or folder.name}: measuring the actor of seed {seed} taken from the shipped file on {episodes} "
              "held-out episodes", flush=True)
        actor.save(path)
        try:
            held_out_record(folder, episodes, per_episode=True, play=play)
        finally:
            path.unlink(missing_ok=True)
            (folder / AVERAGED_SELECT_FILE).unlink(missing_ok=True)  # (written from actor_avg.npz to measure it)


def shipped_members(dest: Path) -> dict[int, LearnedPolicy]:
    """The actors of the file shipped at ``dest`` by training seed: an ensemble's members, or its one actor; empty
    when nothing is shipped there."""
    if not dest.exists():
        return {}
    policy = load_actor(dest)
    members = policy.members if isinstance(policy, EnsemblePolicy) else [policy]
    return {int(m.meta["config"]["seed"]): m for m in members if isinstance(m, LearnedPolicy)}


def kept_seeds(dest: Path, scene: str, algo: str, steps: int, seeds: tuple[int, ...], runs: list[Path],
               fields: dict[str, Any]) -> dict[int, LearnedPolicy]:
    """The seeds to take from the file shipped at ``dest`` rather than train: those whose run folder is not here
    (no final ``actor.npz``, no checkpoint to resume) and whose shipped actor was trained with the configuration
    the recipe gives that seed now (``run_config``) and acting as the agent's play does now (``play_settings``:
    an actor selecting with other settings, or not selecting, is not this agent's), each with its actor. A shipped
    actor trained or acting otherwise (another budget, a recipe changed since) is not kept, and the script says so:
    that seed trains again."""
    shipped = shipped_members(dest)
    kept = {}
    for seed, run in zip(seeds, runs, strict=True):
        if seed not in shipped or (run / "actor.npz").exists() or (run / "checkpoint.pt").exists():
            continue
        want = run_config(scene, algo, steps, seed, fields).to_dict()
        try:
            have = TrainConfig.from_dict(shipped[seed].meta["config"]).to_dict()
        except (ConfigError, KeyError, TypeError, ValueError) as err:
            print(f"{scene} {algo}: the shipped actor of seed {seed} has an unreadable config ({err}); training "
                  "that seed again", flush=True)
            continue
        differ = differing_fields(want, have)
        if differ:
            print(f"{scene} {algo}: the shipped actor of seed {seed} was trained with other {', '.join(differ)} "
                  "than the recipe gives now; training that seed again", flush=True)
            continue
        if shipped[seed].meta.get("select", {}) != play_settings(play_of(algo)):  # (acts otherwise than today's)
            print(f"{scene} {algo}: the shipped actor of seed {seed} selects its actions otherwise "
                  f"({shipped[seed].meta.get('select')}) than {play_of(algo)} does now "
                  f"({play_settings(play_of(algo)) or 'no selection'}); training that seed again", flush=True)
            continue
        kept[seed] = shipped[seed]
    return kept


def kept_logs(scene: str, algo: str, steps: int, seeds: tuple[int, ...], runs: list[Path]) -> set[int]:
    """For DQN and A2C (which ship one chosen run): the seeds whose run folder is not here (no final ``actor.npz``,
    no ``model.zip`` to resume) and whose logs are shipped beside the file from a run of ``steps`` steps. Their
    periodic evaluations take part in the choice of the run again; the shipped file is the actor of the one chosen
    before, the best of them."""
    shipped = {seed: folder for folder, seed in shipped_logs(algo, scene)}
    kept = set()
    for seed, run in zip(seeds, runs, strict=True):
        if seed not in shipped or (run / "actor.npz").exists() or (run / "model.zip").exists():
            continue
        differ = config_differences(shipped[seed], run_config(scene, algo, steps, seed, {}))
        if differ:
            print(f"{scene} {algo}: the shipped run of seed {seed} was trained with other {', '.join(differ)} than "
                  "the recipe gives now; training that seed again", flush=True)
            continue
        kept.add(seed)
    return kept


def is_shipped_run(dest: Path, logs: Path, seed: int, episodes: int) -> bool:
    """Whether the file shipped at ``dest`` is the actor of the DQN or A2C run of ``seed`` whose logs are ``logs``:
    its SHA-256 is the one that run's held-out record names (``heldout_<episodes>.json``), or without that record
    the file's own seed is ``seed``."""
    record = logs / held_out_file(episodes)
    if record.exists():
        digest = json.loads(record.read_text(encoding="utf-8")).get("actor_sha256")
        return digest == hashlib.sha256(dest.read_bytes()).hexdigest()
    return file_seeds(load_actor(dest).meta) == (seed,)


def stage_shipped_logs(scene: str, algo: str, seeds: set[int], into: Path, episodes: int = 100) -> dict[int, Path]:
    """Copy the shipped logs of ``seeds`` (``deck_sim.policies.shipped_logs``) to ``into/seed<k>/``, so that
    ``ship_logs`` can write them back after it clears the logs folder; the folder of each seed that has them. A seed
    without its measurement on ``episodes`` held-out episodes (shipped with another ``--episodes-per-run``) is
    named: ``scripts/make_results.py`` leaves it out of its regime's comparison until its run is measured
    (``measure_kept`` measures MDDPG's and DDPG's)."""
    staged = {}
    for folder, seed in shipped_logs(algo, scene):
        if seed in seeds:
            staged[seed] = into / f"seed{seed}"
            shutil.copytree(folder, staged[seed], ignore=shutil.ignore_patterns("seed*"))
            record = held_out_file(episodes, play_of(algo))
            if not (staged[seed] / record).exists():
                print(f"{scene} {algo}: the shipped logs of seed {seed} hold no {record}", flush=True)
    return staged


def best_run(runs: list[Path]) -> Path:
    """The run whose best periodic evaluation (``eval.csv``'s highest ``success``, seed-500 episodes) is highest;
    on a tie the first of ``runs``. The runs must differ in their seed alone (a folder finished by another command
    with other ``--steps`` or fields is refused, not compared). Raises ``SystemExit`` naming a run without
    evaluations or the fields in which two runs differ."""
    configs = []
    for run in runs:
        config = json.loads((run / "config.json").read_text(encoding="utf-8")) if (run / "config.json").exists() else {}
        configs.append({k: v for k, v in config.items() if k != "seed"})
    differ = sorted({k for c in configs[1:] for k in c.keys() | configs[0].keys() if c.get(k) != configs[0].get(k)})
    if differ:
        raise SystemExit(f"the runs {[str(r) for r in runs]} differ in more than their seed ({', '.join(differ)}); "
                         "train them again or remove one")
    best: tuple[float, int] | None = None
    for i, run in enumerate(runs):
        with open(run / "eval.csv", newline="") as f:
            rates = [float(row["success"]) for row in csv.DictReader(f)]
        if not rates:
            raise SystemExit(f"{run}: no periodic evaluation in eval.csv to choose the shipped run by")
        if best is None or max(rates) > best[0]:
            best = (max(rates), i)
    return runs[best[1]]


def run_folder(out: Path, scene: str, algo: str, seed: int) -> Path:
    """Where the run behind ``deck_sim/trained/<scene>_<algo>.npz`` lives: ``<recipe>-<training algo>-seed<seed>``
    (``deck1-mddpg-seed0``, ``deck1-reward-mddpg-seed0``)."""
    return out / f"{recipe_name(algo, scene)}-{training_algo(algo)}-seed{seed}"


def default_steps(scene: str, algo: str) -> int:
    """Environment steps of one run of the recipe of the shipped ``algo`` of ``scene``."""
    return load_recipe(recipe_name(algo, scene)).steps(training_algo(algo))


def default_seeds(scene: str, algo: str) -> tuple[int, ...]:
    """The training seeds behind the shipped ``algo`` of ``scene``: its recipe's."""
    return load_recipe(recipe_name(algo, scene)).seeds(training_algo(algo))


def run_config(scene: str, algo: str, steps: int, seed: int, fields: dict[str, Any]) -> Any:
    """What one run of the shipped ``algo`` of ``scene`` trains with: its recipe's ``TrainConfig`` (MDDPG, DDPG;
    ``deck-sim train --recipe <recipe> --algo <training algo> --seed <seed> --print-config`` prints the same) or the
    keyword arguments of ``train_baseline`` (DQN, A2C), ``steps`` and ``fields`` applied."""
    return load_recipe(recipe_name(algo, scene)).run(training_algo(algo), seed, steps,
                                                     **(fields if algo in DDPG_ALGOS else {}))


def train(run: Path, scene: str, algo: str, steps: int, seed: int, fields: dict[str, Any]) -> None:
    """Train (or resume) the run unless it has finished (a final ``actor.npz``); ``SystemExit`` if the folder holds
    a run of another configuration than the recipe gives now (its length aside: ``--steps`` may extend a run)."""
    plan = run_config(scene, algo, steps, seed, fields)
    if (run / "config.json").exists() and (differ := [f for f in config_differences(run, plan) if f != "total_steps"]):
        raise SystemExit(f"{run}: a run trained with other {', '.join(differ)} than the recipe gives now; move it "
                         "away (or give another --out) to train the recipe's run there")
    if (run / "actor.npz").exists():
        return
    if algo in DDPG_ALGOS:
        from training.loop import Trainer

        resume = (run / "checkpoint.pt").exists()
        print(f"training {algo} on {scene} ({steps} steps) in {run}" + (" (resuming)" if resume else ""), flush=True)
        summary = Trainer(plan, run, resume=resume, progress=False).train()
    else:
        from training.baselines import train_baseline

        resume = (run / "model.zip").exists()
        print(f"training {algo} on {scene} ({steps} steps) in {run}" + (" (resuming)" if resume else ""), flush=True)
        summary = train_baseline(**plan, out=run, resume=resume, progress=False)
    if summary.get("stopped"):  # interrupted: nothing may be shipped or measured from an unfinished run
        raise SystemExit(f"{run}: stopped at step {summary.get('step', '?')}; run the same command again to resume")


@contextlib.contextmanager
def locked_report() -> Iterator[dict[str, dict[str, dict]]]:
    """``results.json`` read and written under an exclusive lock (other copies of this script may run)."""
    path = TRAINED_DIR / "results.json"
    with open(Path(tempfile.gettempdir()) / "deck_sim_train_shipped.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        report = read_report(path)
        yield report
        write_atomic(path, json.dumps(report, indent=2, sort_keys=True) + "\n")
        write_readme(report)


def write_atomic(path: Path, text: str) -> None:
    """Replace ``path`` by ``text`` in one step (a reader sees the old file or the new one, never half), keeping
    the file's permissions; the temporary file is removed if writing fails."""
    tmp = path.with_name(path.name + ".tmp")
    try:
        tmp.write_text(text, encoding="utf-8")
        if path.exists():
            shutil.copymode(path, tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def shipped_records(report: dict[str, dict[str, dict]]) -> Iterator[tuple[str, str, dict]]:
    """``(scene, algo, record)`` in the tables' order: scenes by name, agents as in ``SHIPPED_ALGOS``."""
    order = {a: i for i, a in enumerate(SHIPPED_ALGOS)}
    for scene in sorted(report):
        for algo in sorted(report[scene], key=lambda a: order.get(a, len(order))):
            yield scene, algo, report[scene][algo]


def read_report(path: Path) -> dict[str, dict[str, dict]]:
    """``{scene: {algo: figures}}``; an older file with one MDDPG record per scene is read as such."""
    report = json.loads(path.read_text()) if path.exists() else {}
    report = {scene: ({"mddpg": r} if "success" in r else r) for scene, r in report.items()}
    for agents in report.values():  # records from before ensembles name one ``seed``
        for r in agents.values():
            if "seeds" not in r and "seed" in r:
                r["seeds"] = [r.pop("seed")]
    return report


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", default="deck1,deck2,square")
    parser.add_argument("--algos", default=None,
                        help=f"agents to ship (default all: {','.join(SHIPPED_ALGOS)}; with --evaluate-only, all "
                             "that are shipped)")
    parser.add_argument("--steps", type=int, default=None,
                        help="training steps for every agent (default: the scene's recipe)")
    parser.add_argument("--seeds", default=None,
                        help="training seeds, comma-separated (default: the scene's recipe); with several seeds "
                             "MDDPG and DDPG ship the mean action of their actors, DQN and A2C the run with the best "
                             "periodic evaluation")
    parser.add_argument("--episodes", type=int, default=200, help="held-out episodes per agent (seed 1000)")
    parser.add_argument("--out", default="runs/learning", help="run folders, <out>/<scene>-<algo>-seed<seed>")
    parser.add_argument("--episodes-per-run", type=int, default=100,
                        help="episodes of docs/results.md on which each run's actor is measured "
                             "(training.heldout; shipped as heldout_<N>.json beside the actor's logs, "
                             "heldout_<N>_<play>.json for an agent acting otherwise)")
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--evaluate-only", action="store_true", help="measure the shipped files again (no training)")
    mode.add_argument("--redo", action="store_true", help="copy and measure again agents already shipped")
    mode.add_argument("--tables-only", action="store_true",
                      help="rewrite deck_sim/trained/README.md and the README's table from results.json, nothing else")
    parser.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                        help="TrainConfig overrides (MDDPG and DDPG runs)")
    args = parser.parse_args()
    if args.tables_only:
        write_readme(read_report(TRAINED_DIR / "results.json"))
        print(f"wrote {TRAINED_DIR / 'README.md'} and the table in {PROJECT_README}")
        return
    fields = {}
    for item in args.set:
        k, _, v = item.partition("=")
        fields[k] = json.loads(v)
    if "forecast" in fields:  # (the shipped MDDPG observes the paper's MPC forecast; another is a diagnostic)
        raise SystemExit("--set forecast: the shipped MDDPG observes the MPC forecast; train other forecasts with "
                         "deck-sim train or benchmarks/learning.py")
    algos = args.algos.split(",") if args.algos else list(SHIPPED_ALGOS)
    unknown = sorted(set(algos) - set(SHIPPED_ALGOS))
    if unknown:
        raise SystemExit(f"unknown agents {unknown}; expected some of {', '.join(SHIPPED_ALGOS)}")
    try:
        seeds_given = tuple(int(x) for x in args.seeds.split(",")) if args.seeds else None
    except ValueError:
        raise SystemExit(f"--seeds {args.seeds!r}: expected comma-separated integers") from None
    if seeds_given is not None and len(set(seeds_given)) < len(seeds_given):
        raise SystemExit(f"--seeds {args.seeds!r}: each seed once")
    if seeds_given is not None and args.evaluate_only:
        raise SystemExit("--seeds with --evaluate-only: the shipped files' own seeds are measured (drop --seeds)")
    TRAINED_DIR.mkdir(exist_ok=True)
    out = Path(args.out)
    shipped = read_report(TRAINED_DIR / "results.json")
    work = []
    for scene in args.scenes.split(","):
        for algo in algos:
            dest = TRAINED_DIR / f"{scene}_{algo}.npz"
            if not args.evaluate_only and recipe_name(algo, scene) not in recipe_names():
                message = f"{scene} {algo}: no recipe training/recipes/{recipe_name(algo, scene)}.toml"
                if args.algos:  # asked for by name: refuse
                    raise SystemExit(f"{message}; recipes: {', '.join(recipe_names())}")
                print(f"{message}; skipped", flush=True)
                continue
            if args.evaluate_only and not args.algos and not dest.exists():
                print(f"{scene} {algo}: not shipped, not measured", flush=True)
                continue
            seeds = seeds_given or default_seeds(scene, algo)
            if (not args.evaluate_only and play_of(algo) == "averaged-select"
                    and run_config(scene, algo, args.steps or default_steps(scene, algo), seeds[0],
                                   fields).actor_average <= 0):
                message = (f"{scene} {algo}: training/recipes/{recipe_name(algo, scene)}.toml keeps no averaged actor "
                           f"(actor_average), which {algo} acts through")
                if args.algos:
                    raise SystemExit(message)
                print(f"{message}; skipped", flush=True)
                continue
            if algo in DDPG_ALGOS:  # the seeds whose actors the shipped file holds
                in_file = set(shipped_members(dest))
            else:  # the seeds the shipped run was chosen from
                record = shipped.get(scene, {}).get(algo, {}) if dest.exists() else {}
                in_file = set(record.get("trained_seeds") or record.get("seeds") or [])
            gains = bool(in_file) and in_file < set(seeds)  # shipped with some of the seeds asked for
            if not (args.evaluate_only or args.redo) and dest.exists() and algo in shipped.get(scene, {}) and not gains:
                print(f"{scene} {algo}: shipped and measured already ({dest}; --redo to measure again)", flush=True)
                continue
            runs = [run_folder(out, scene, algo, seed) for seed in seeds]
            todo = sum(not (r / "actor.npz").exists() and s not in in_file for s, r in zip(seeds, runs, strict=True))
            cost = 0  # environment steps still to train, a DDPG step counted as two (its updates cost as much)
            if todo and not args.evaluate_only:
                cost = todo * (args.steps or default_steps(scene, algo)) * (2 if algo in DDPG_ALGOS else 1)
            work.append((cost, len(work), scene, algo, seeds, runs, dest))
    for _, _, scene, algo, seeds, runs, dest in sorted(work):
        steps = args.steps if args.steps is not None else default_steps(scene, algo)
        if args.evaluate_only:
            if not dest.exists():
                raise SystemExit(f"--evaluate-only: no shipped policy {dest}")
            kept: Mapping[int, LearnedPolicy | None] = {}
        elif algo in DDPG_ALGOS:
            kept = kept_seeds(dest, scene, algo, steps, seeds, runs, fields)
        else:  # (their actors are not shipped: their logs alone, for the choice)
            kept = dict.fromkeys(kept_logs(scene, algo, steps, seeds, runs) if dest.exists() else ())
        with staging_folder(scene, algo, dest, bool(kept)) as staging:
            if not args.evaluate_only:
                runs = train_and_ship(scene, algo, seeds, runs, dest, steps, fields, kept, staging,
                                      args.episodes_per_run)
            measure_and_record(scene, algo, dest, runs, args.episodes, shipped)


@contextlib.contextmanager
def staging_folder(scene: str, algo: str, dest: Path, needed: bool) -> Iterator[Path | None]:
    """A temporary folder for the shipped logs of the seeds kept from ``dest`` while they are shipped again (None if
    none is kept); removed once the agent is shipped and measured, kept (and named) if anything in the block raises,
    the measurement included."""
    if not needed:
        yield None
        return
    staging = Path(tempfile.mkdtemp(prefix=f"deck_sim-shipped-logs-{scene}_{algo}-"))
    try:
        yield staging
    except BaseException:
        print(f"{scene} {algo}: stopped; a copy of the shipped logs of the seeds kept from {dest.name} is in "
              f"{staging} (they are also in git)", flush=True)
        raise
    shutil.rmtree(staging, ignore_errors=True)


def train_and_ship(scene: str, algo: str, seeds: tuple[int, ...], runs: list[Path], dest: Path, steps: int,
                   fields: dict[str, Any], kept: Mapping[int, LearnedPolicy | None], staging: Path | None,
                   episodes_per_run: int) -> list[Path]:
    """Train each seed's run that is not ``kept``, ship the actor (``ship``) and every seed's logs (``ship_logs``).

    ``kept``: the seeds taken from the shipped file (MDDPG/DDPG: their actors; DQN/A2C: None, their logs alone).
    MDDPG and DDPG ship the ensemble of every seed's actor. DQN and A2C ship the best run's actor, or leave the
    shipped file as it is when the best run is a kept seed's; before anything trains, ``SystemExit`` if that file
    is not the actor of the best kept run. Returns the folders whose logs were shipped (a kept seed's staged copy
    in ``staging``), the shipped run first for DQN and A2C."""
    staged = stage_shipped_logs(scene, algo, set(kept), staging or Path(), episodes_per_run)
    measure_kept(kept, staged, episodes_per_run, f"{scene} {algo}", play_of(algo))
    if algo not in DDPG_ALGOS and kept:  # the shipped file must be the best kept run's, or none is right
        order = sorted(kept)
        best = order[[staged[k] for k in order].index(best_run([staged[k] for k in order]))]
        if not is_shipped_run(dest, staged[best], best, episodes_per_run):
            raise SystemExit(f"{scene} {algo}: {dest.name} is not the actor of seed {best}, the best of "
                             f"the shipped runs {order}; run with their run folders, or --redo with "
                             "--seeds of the runs that are here")
    for seed, run in zip(seeds, runs, strict=True):
        if seed in kept:
            print(f"{scene} {algo}: seed {seed} as shipped with {dest.name} (no run folder {run})", flush=True)
            continue
        train(run, scene, algo, steps, seed, fields)
        held_out_record(run, episodes_per_run, play=play_of(algo))  # docs/results.md's episodes, shipped beside it
    if algo in DDPG_ALGOS:
        ship([kept.get(seed, run) for seed, run in zip(seeds, runs, strict=True)], dest, play_of(algo))
        runs = [staged.get(seed, run) for seed, run in zip(seeds, runs, strict=True)]
    else:  # one run, the others' logs beside it
        candidates = [staged.get(seed, run) for seed, run in zip(seeds, runs, strict=True)]
        chosen = candidates.index(best_run(candidates))
        if seeds[chosen] not in kept:
            ship([runs[chosen]], dest)
        # (else the shipped file, the best kept run's as checked before training, stays)
        order = [chosen, *(i for i in range(len(candidates)) if i != chosen)]
        runs, seeds = [candidates[i] for i in order], tuple(seeds[i] for i in order)
    ship_logs(runs, seeds, scene, algo, episodes_per_run)
    return runs


def measure_and_record(scene: str, algo: str, dest: Path, runs: list[Path], episodes: int,
                       shipped: dict[str, dict[str, dict]]) -> None:
    """Measure the shipped ``dest`` on ``episodes`` held-out episodes and write its record to ``results.json``
    (which rewrites ``deck_sim/trained/README.md`` and the project README's table, ``locked_report``).

    ``runs``: the folders of its runs' logs, read for the training time only when the logs shipped with the policy
    do not cover every seed; ``shipped``: ``results.json`` as it was, for the time last recorded."""
    t0 = time.perf_counter()
    summary = held_out(dest, scene, episodes)
    meta = load_actor(dest).meta
    seeds = file_seeds(meta)  # the file's own record (``--evaluate-only`` measures whatever is shipped)
    # every seed trained for it: an ensemble's members, or the runs a stable-baselines3 agent was chosen from
    shipped_runs = shipped_logs(algo, scene)
    logs = [folder for folder, _ in shipped_runs]
    trained = sorted({s for _, s in shipped_runs if s is not None} | set(seeds))
    # the training time from the logs shipped with the policy (a run folder may hold a newer, unshipped run),
    # else from the runs' logs, else as last recorded (``--evaluate-only`` without the run folders keeps it)
    if len(logs) != len(trained):
        logs = [r for r in runs if (r / "eval.csv").exists()]
    if len(logs) == len(trained):  # every run's log, or the sum would leave a run out
        wall = sum(_train_wall(d) for d in logs)
    else:
        wall = float(shipped.get(scene, {}).get(algo, {}).get("train_wall_s", "nan"))
        print(f"{scene} {algo}: {len(logs)} training logs for {len(trained)} runs; training time kept as "
              f"recorded ({wall:.0f} s)", flush=True)
    record = {
        "algo": algo,
        "episodes": episodes,
        "held_out_seed": HELD_OUT_SEED,
        "success": summary["goal_rate"],
        "collision": summary["collision_rate"],
        "timeout": summary["timeout_rate"],
        "off_surface": summary["off_surface_rate"],
        "mean_reward": summary["mean_reward"],
        "path_ratio": summary["path_ratio"],
        "turning_angle_deg": summary["turning_angle_deg"],
        "predictor": str(meta.get("predictor", "none")),
        "recipe": f"training/recipes/{recipe_name(algo, scene)}.toml [{AGENTS[algo].trainer}]",
        "train_steps": int(meta["config"]["total_steps"]),
        "selected_at_step": int(meta["trained_steps"]),  # an ensemble's first member's (each one's: its ``members``)
        "git_commit": str(meta.get("git_commit", "")),  # the first run's (each run's: ``git_commits``)
        "git_commits": [str(m.get("git_commit", "")) for m in meta.get("members") or [meta]],
        "train_wall_s": wall,
        "seeds": list(seeds),
        "trained_seeds": trained,  # (a stable-baselines3 agent ships the best of these runs)
        "file_kib": dest.stat().st_size / 1024,
        "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores",
    }
    with locked_report() as report:  # read just before writing: another run may have finished meanwhile
        report.setdefault(scene, {})[algo] = record
    print(
        f"{scene} {algo}: held-out success {100 * summary['goal_rate']:.1f} % over {episodes} episodes "
        f"(evaluated in {time.perf_counter() - t0:.0f} s); wrote {dest}",
        flush=True,
    )


def _train_wall(run: Path) -> float:
    with open(run / "eval.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    return float(rows[-1]["wall_s"]) if rows else float("nan")


def write_readme(report: dict[str, dict[str, dict]]) -> None:
    """Write ``deck_sim/trained/README.md`` (``readme_text``) and the project README's table from ``report``."""
    write_atomic(TRAINED_DIR / "README.md", readme_text(report))
    write_project_table(report)


def readme_text(report: dict[str, dict[str, dict]]) -> str:
    """``deck_sim/trained/README.md``: how the shipped files were made, and every agent's held-out figures."""
    lines = [
        "# Shipped policies",
        "",
        "Weights-only actors (`deck_sim.policies.LearnedPolicy`, numpy alone; `load_actor` reads them), written by",
        "`python scripts/train_shipped.py`; this page is written by that script too. MDDPG and DDPG are",
        "`training.loop.Trainer` runs of the recipe in the table (`training/recipes/<scene>.toml`, from the reward",
        "alone `<scene>-reward.toml`, from the planner on the agent's observation `<scene>-planner.toml`; DDPG: the",
        "same",
        "agent, recipe, seeds and budget without the MPC prediction), one run per training seed; with several seeds",
        "the file holds each run's actor and acts by the mean of their actions (`deck_sim.policies.EnsemblePolicy`).",
        "DQN and A2C are stable-baselines3 runs",
        "(`training.baselines`) exported to numpy; with several seeds they ship one run, the seed whose best periodic",
        "evaluation is highest (a mean of DQN's discrete displacements would not be DQN). A run that ends with the",
        "cloning fit (`polish`) ships its final,",
        "fitted actor (`training.loop.shipped_actor`); any other run the actor of its best periodic evaluation",
        "(seed-500 episodes): the column `actor` says which. The agents named `-select` are the same runs as the",
        "agent without the suffix, each acting through its final slow average of its actor (`actor_avg.npz`) with",
        "its own critic choosing each action among candidates around that actor's (`training.final_fit.PLAYS`).",
        "Held-out:",
        "consecutive episodes of",
        "`deck_sim.load(scene, seed=1000)`, the stream of `deck-sim run --scene <scene> --policy <agent> --seed 1000`",
        "(never a training, demonstration or model-selection episode). Training time: wall-clock of the runs, summed,",
        "periodic evaluations included, while other work shared the machine; `machine` in `results.json` names",
        "the machine of the held-out measurement, which `--evaluate-only` repeats without training.",
        "`learnt from` is the training regime (`deck_sim.policies.regimes`): `reward` (the reward alone), `planner`",
        "(also a planner that sees what the agent sees) or `oracle-teacher` (also the full-knowledge planner).",
        "",
        "| scene | agent | learnt from | recipe | training seeds | actor | held-out episodes | success | collision |"
        " timeout | left the deck | mean reward | path / straight | turning angle | training steps (each seed) |"
        " training time (all seeds) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for scene, algo, r in shipped_records(report):
        recipe = f"`training/recipes/{recipe_name(algo, scene)}.toml` [{'ddpg' if algo in DDPG_ALGOS else 'sb3'}]"
        if drift := shipped_drift(scene, algo):  # (the recipe changed after this file shipped)
            recipe += f" ({drift})"
        # which actor the file is: its own record says
        meta = load_actor(TRAINED_DIR / f"{scene}_{algo}.npz").meta
        members = meta.get("members") or []
        if (members or [meta])[0].get("select"):  # (an averaged actor acting through its critic: each member's)
            steps = ", ".join(str(m.get("trained_steps", "?")) for m in members or [meta])
            actor = f"its averaged actor choosing by its critic ({steps} steps)"
        elif meta.get("polished", False):
            actor = "final, fitted"
        elif members:  # each member its own run's best evaluation, at its own step
            actor = f"its best evaluation ({', '.join(str(m.get('trained_steps', '?')) for m in members)} steps)"
        else:
            actor = f"best evaluation ({r['selected_at_step']} steps)"
        if members:
            actor = f"mean action of {len(members)} actors, each {actor}"
        seeds = ", ".join(map(str, r.get("seeds", [])))
        if len(r.get("trained_seeds", [])) > len(r.get("seeds", [])):
            actor += f", of the seed whose best evaluation was highest of {', '.join(map(str, r['trained_seeds']))}"
        lines.append(
            f"| {scene} | {LABELS.get(algo, algo)} | {learnt_from(scene, algo)} | {recipe} | {seeds} | {actor} | "
            f"{r['episodes']} | "
            f"{100 * r['success']:.1f} % | "
            f"{100 * r['collision']:.1f} % | {100 * r['timeout']:.1f} % | {100 * r['off_surface']:.1f} % | "
            f"{r['mean_reward']:.1f} | {r['path_ratio']:.3f} | {r['turning_angle_deg']:.1f} deg | "
            f"{r['train_steps']} | {r['train_wall_s'] / 60:.0f} min |"
        )
    return "\n".join(lines) + "\n"


def learnt_from(scene: str, algo: str) -> str:
    """The regime the shipped ``algo`` of ``scene`` learnt in (``deck_sim.policies.regimes``), read from its
    shipped training config; stable-baselines3 learns from the environment's reward alone."""
    if AGENTS[algo].trainer == "sb3":
        return "reward"
    config = json.loads((shipped_log_dir(algo, scene) / "config.json").read_text(encoding="utf-8"))
    return config_regime(config)


def project_table(report: dict[str, dict[str, dict]]) -> list[str]:
    """The project README's shipped-policies table: what each agent learnt from, held-out rates, training steps
    and wall-clock minutes."""
    lines = [
        "| scene | agent | learnt from | training seeds | success | collision | timeout | left the deck / square |"
        " training steps (each seed) | training time (all seeds, under load) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for scene, algo, r in shipped_records(report):
        runs = seeds_text(r.get("seeds", []), r.get("trained_seeds"))
        learnt = learnt_from(scene, algo)
        if drift := shipped_drift(scene, algo):
            learnt += f" ({drift})"
        lines.append(
            f"| {scene} | {LABELS.get(algo, algo)} | {learnt} | {runs} | "
            f"{100 * r['success']:.1f} % | "
            f"{100 * r['collision']:.1f} % | "
            f"{100 * r['timeout']:.1f} % | {100 * r['off_surface']:.1f} % | {r['train_steps']:,} | "
            f"{r['train_wall_s'] / 60:.0f} min |"
        )
    return lines


def write_project_table(report: dict[str, dict[str, dict]], path: Path = PROJECT_README) -> bool:
    """Rewrite the table between ``README_MARKERS`` in ``path`` (atomically); without both markers, in order,
    leave the file alone, say so and return False (``results.json`` and ``deck_sim/trained/README.md`` are written
    either way)."""
    text = path.read_text(encoding="utf-8") if path.exists() else ""
    if [text.count(m) for m in README_MARKERS] != [1, 1]:
        print(f"warning: {path} does not hold each shipped-table marker {README_MARKERS} exactly once; its table "
              "was not updated", flush=True)
        return False
    start = text.index(README_MARKERS[0]) + len(README_MARKERS[0])
    end = text.find(README_MARKERS[1], start)
    if end < 0:
        print(f"warning: {path}: the shipped-table end marker comes before its start; its table was not updated",
              flush=True)
        return False
    write_atomic(path, text[:start] + "\n" + "\n".join(project_table(report)) + "\n" + text[end:])
    return True


if __name__ == "__main__":
    main()

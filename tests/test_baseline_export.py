"""DQN and A2C exported from stable-baselines3 to weights-only numpy files: the same actions as SB3's own
``predict``, loadable by name (``make_policy("dqn" | "a2c")``, ``deck-sim run --policy dqn``), clear errors on
corrupt files."""

from __future__ import annotations

import json
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest

import deck_sim
from deck_sim.agents import AGENTS
from deck_sim.policies import (
    EnsemblePolicy,
    LearnedPolicy,
    PolicyFileError,
    load_actor,
    make_policy,
    seeds_text,
    shipped_logs,
    write_actor_file,
)
from training.recipes import shipped_drift

SHORT = {"dqn": {"learning_starts": 20, "buffer_size": 1000}, "a2c": {"n_steps": 8}}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """One short seeded SB3 run per baseline on deck 1 (its final actor.npz is the export under test)."""
    from training.baselines import train_baseline

    root = tmp_path_factory.mktemp("sb3")
    for algo, kwargs in SHORT.items():
        train_baseline(algo, "deck1", 64, 0, root / algo, progress=False, eval_every=0, eval_episodes=1, **kwargs)
    return root


def _observations(n: int = 40, seed: int = 3) -> list[dict[str, np.ndarray]]:
    env = deck_sim.load("deck1", seed=seed, episode__predictor="none")
    rng = np.random.default_rng(seed)
    ts, out = env.reset(), []
    for _ in range(n):
        out.append(ts.observation)
        ts = env.step(rng.uniform(-1.0, 1.0, 2))
        if ts.last():
            ts = env.reset()
    return out


@pytest.mark.slow
@pytest.mark.parametrize("algo", ["dqn", "a2c"])
def test_the_numpy_export_acts_as_sb3_predicts(runs, algo):
    from training.baselines import discrete_actions, load_baseline

    sb3 = load_baseline(runs / algo)
    exported = LearnedPolicy.load(runs / algo / "actor.npz")
    assert exported.predictor == "none" and exported.meta["algo"] == algo and exported.meta["scene"] == "deck1"
    assert exported.head == ("argmax" if algo == "dqn" else "clip")
    assert exported.activation == ("relu" if algo == "dqn" else "tanh")  # SB3's defaults for each
    observations = _observations()
    ours = np.array([exported.act(o) for o in observations])
    # SB3's predict on the VecNormalize-normalised float32 observation, as the SB3 policy acts in training
    x = np.stack([np.concatenate([np.ravel(o[k]) for k in sb3.keys]) for o in observations]).astype(np.float32)
    predicted, _ = sb3.model.predict(sb3.vecnormalize.normalize_obs(x), deterministic=True)
    if algo == "dqn":
        theirs = discrete_actions()[predicted]
        np.testing.assert_array_equal(ours, theirs)
        assert len({tuple(a) for a in ours}) > 1  # not a degenerate constant, or the comparison proves little
    else:
        theirs = np.clip(predicted, -1.0, 1.0)
        np.testing.assert_allclose(ours, theirs, atol=1e-5)
        assert np.ptp(ours, axis=0).max() > 1e-3
    assert (runs / algo / "actor_best.npz").exists()
    assert (runs / algo / "actor.npz").stat().st_size < 1024 * 1024  # weights only


@pytest.mark.parametrize("algo", ["dqn", "a2c"])
def test_make_policy_and_deck_sim_run_load_the_shipped_name(runs, algo, tmp_path, monkeypatch, capsys):
    import deck_sim.policies.registry as policies
    from deck_sim.cli import main

    monkeypatch.setattr(policies, "TRAINED_DIR", tmp_path)
    with pytest.raises(PolicyFileError, match=f"no shipped {algo} policy for scene 'deck1'"):
        make_policy(algo, deck_sim.load("deck1", seed=0, episode__predictor="none"))
    shutil.copyfile(runs / algo / "actor.npz", tmp_path / f"deck1_{algo}.npz")
    env = deck_sim.load("deck1", seed=1000, episode__predictor="none")
    policy = make_policy(algo, env)
    ts = env.reset()
    for _ in range(3):
        action = policy.act(ts.observation)
        assert action.shape == (2,) and np.all(np.abs(action) <= 1.0)
        ts = env.step(action)
    assert main(["run", "--scene", "deck1", "--policy", algo, "--episodes", "1", "--no-record", "--quiet"]) == 0
    assert "predictor none" in capsys.readouterr().out  # the baselines observe the current state only


def test_corrupt_or_inconsistent_exports_give_clear_errors(runs, tmp_path):
    src = runs / "dqn" / "actor.npz"
    truncated = tmp_path / "truncated.npz"
    truncated.write_bytes(src.read_bytes()[:1000])
    with pytest.raises(PolicyFileError, match="truncated.npz: not a readable actor file"):
        LearnedPolicy.load(truncated)
    with np.load(src) as data:
        arrays = {k: data[k] for k in data.files}
    meta = json.loads(str(arrays.pop("meta")))

    def broken(name: str, meta_changes: dict | None = None, drop: str | None = None, **array_changes):
        path = tmp_path / name
        out = {k: v for k, v in {**arrays, **array_changes}.items() if k != drop}
        write_actor_file(path, out, {**meta, **(meta_changes or {})}, compress=False)
        return path

    with pytest.raises(PolicyFileError, match="no_table.npz: not a complete deck_sim actor.*action_table"):
        LearnedPolicy.load(broken("no_table.npz", drop="action_table"))
    with pytest.raises(PolicyFileError, match="short_table.npz: expected 50 inputs and 5 outputs"):
        LearnedPolicy.load(broken("short_table.npz", action_table=arrays["action_table"][:5]))
    with pytest.raises(PolicyFileError, match="head 'softmax'"):
        LearnedPolicy.load(broken("head.npz", {"head": "softmax"}))
    with pytest.raises(PolicyFileError, match="activation 'gelu'"):
        LearnedPolicy.load(broken("act.npz", {"activation": "gelu"}))
    with pytest.raises(PolicyFileError, match="format 'sb3/9'"):
        LearnedPolicy.load(broken("format.npz", {"format": "sb3/9"}))
    with pytest.raises(PolicyFileError, match="NaN or infinite"):
        LearnedPolicy.load(broken("nan.npz", w1=np.full_like(arrays["w1"], np.nan)))
    with pytest.raises(PolicyFileError, match="shape"):  # trained on deck 1, asked to act on deck 2
        LearnedPolicy.load(src).act(deck_sim.load("deck2", seed=0, episode__predictor="none").reset().observation)


def _shipped_agents() -> dict[str, dict[str, dict]]:
    """``deck_sim/trained/results.json`` as ``{scene: {algo: figures}}`` (scripts/train_shipped.py writes it)."""
    from deck_sim.policies import TRAINED_DIR

    report = json.loads((TRAINED_DIR / "results.json").read_text())
    return {scene: ({"mddpg": r} if "success" in r else r) for scene, r in report.items()}


@pytest.mark.slow
@pytest.mark.parametrize("scene", ["deck1", "deck2", "square"])
def test_every_agent_is_measured_shipped_small_and_acts_by_name(scene):
    from deck_sim.policies import SHIPPED_ALGOS, load_actor, policy_overrides, shipped_policy_path

    agents = _shipped_agents()[scene]
    # all four learned agents of the paper, measured and shipped (and any other shipped agent of the registry)
    assert {"mddpg", "ddpg", "dqn", "a2c"} <= set(agents) <= set(SHIPPED_ALGOS)
    for algo, record in agents.items():
        path = shipped_policy_path(algo, scene)
        shipped = load_actor(path)
        actors = len(getattr(shipped, "members", [shipped]))  # (an ensemble holds one actor per seed)
        # small: weights only, no optimiser or replay (an actor that selects carries its critic too)
        selects = any(getattr(m, "selects", False) for m in getattr(shipped, "members", [shipped]))
        assert path.stat().st_size < actors * (3.0 if selects else 1.5) * 1024 * 1024
        if (AGENTS[algo].algo or algo) == "mddpg":  # acts with the MPC forecast: test_trainer.py, test_regimes.py
            continue
        # each actor's own observation (DDPG on deck 1 also observes the movers' sizes)
        env = deck_sim.load(scene, seed=1000, **policy_overrides(algo, scene))
        policy = make_policy(algo, env)
        assert policy.predictor == "none" and policy.meta["scene"] == scene
        assert int(policy.meta["config"]["total_steps"]) == record["train_steps"]
        assert record["episodes"] == 200 and record["held_out_seed"] == 1000
        ts = env.reset()
        for _ in range(3):
            action = policy.act(ts.observation)
            assert action.shape == (2,) and np.all(np.abs(action) <= 1.0)
            ts = env.step(action)


def _train_shipped():
    """``scripts/train_shipped.py`` as a module (it is a script, not part of the package)."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "scripts" / "train_shipped.py"
    spec = importlib.util.spec_from_file_location("train_shipped", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_project_readme_table_matches_results_json():
    """The README's shipped-policies table is the figures of ``results.json``, not a hand copy that can drift
    (``scripts/train_shipped.py`` rewrites the rows between the two markers)."""
    script = _train_shipped()
    text = script.PROJECT_README.read_text(encoding="utf-8")
    assert [text.count(m) for m in script.README_MARKERS] == [1, 1]
    start, end = (text.index(m) for m in script.README_MARKERS)
    assert start < end
    rows = [line for line in text[start:end].splitlines() if line.startswith("| ") and "%" in line]
    labels = {label: algo for algo, label in script.LABELS.items()}
    seen = set()
    for line in rows:
        cells = (c.strip() for c in line.strip("|").split("|"))
        scene, label, learnt, runs, success, collision, timeout, off, steps, wall = cells
        record = _shipped_agents()[scene][labels[label]]
        agent = AGENTS[labels[label]]
        learnt, _, note = learnt.partition(" (")  # (a file shipped before its recipe changed says so)
        assert learnt == ("reward" if agent.trainer == "sb3" else agent.recipe or "oracle-teacher")
        drift = shipped_drift(scene, labels[label])
        assert note == (f"{drift})" if drift else ""), (scene, label)
        assert runs == seeds_text(record["seeds"], record.get("trained_seeds")), (scene, label)
        assert runs.startswith(f"{len(record['seeds'])} (seed")
        for cell, key in ((success, "success"), (collision, "collision"), (timeout, "timeout"), (off, "off_surface")):
            assert cell == f"{100 * record[key]:.1f} %", (scene, label, key)
        assert int(steps.replace(",", "")) == record["train_steps"], (scene, label)
        assert wall == f"{record['train_wall_s'] / 60:.0f} min", (scene, label)
        seen.add((scene, labels[label]))
    assert seen == {(s, a) for s, agents in _shipped_agents().items() for a in agents}  # every shipped agent, once
    assert len(rows) == len(seen)


def test_the_shipped_policies_page_is_the_scripts_own_output(tmp_path):
    """``deck_sim/trained/README.md`` is what ``train_shipped.py`` writes from ``results.json`` (an edit of the
    script's text without a rerun, or a hand edit of the page, shows here), and ``results.json`` records from
    before ensembles (one ``seed``) read as one-seed records."""
    from deck_sim.policies import TRAINED_DIR

    script = _train_shipped()
    report = script.read_report(TRAINED_DIR / "results.json")
    text = script.readme_text(report)
    assert text == (TRAINED_DIR / "README.md").read_text(encoding="utf-8")
    # an ensemble of best evaluations names each member's own step (the runs peak at different steps)
    for scene, algo, _ in script.shipped_records(report):
        meta = load_actor(TRAINED_DIR / f"{scene}_{algo}.npz").meta
        if meta.get("members") and not meta.get("polished", False):
            at = ", ".join(str(m["trained_steps"]) for m in meta["members"])
            row = next(line for line in text.splitlines() if line.startswith(f"| {scene} | {script.LABELS[algo]} |"))
            # (an agent acting through each run's averaged actor and critic names that, at the runs' last step)
            way = "its averaged actor choosing by its critic" if meta["members"][0].get("select") else \
                "its best evaluation"
            assert f"each {way} ({at} steps)" in row, (scene, algo)
    legacy = tmp_path / "results.json"
    legacy.write_text(json.dumps({"deck1": {"dqn": {"success": 0.5, "seed": 4}}}))
    assert script.read_report(legacy) == {"deck1": {"dqn": {"success": 0.5, "seeds": [4]}}}
    assert seeds_text([4]) == "1 (seed 4)" and seeds_text([0, 1]) == "2 (seeds 0, 1; mean action)"
    assert seeds_text([1], [0, 1, 2]) == "1 (seed 1, the best of seeds 0, 1, 2)"


def test_a_stable_baselines3_agent_ships_the_run_with_the_best_periodic_evaluation(tmp_path):
    script = _train_shipped()
    runs = []
    for seed, rates in enumerate([(0.2, 0.6, 0.5), (0.7, 0.4), (0.3, 0.7)]):  # seed 1 first reaches the highest
        run = tmp_path / f"seed{seed}"
        run.mkdir()
        rows = "".join(f"{50_000 * (k + 1)},{k},100,{r}\n" for k, r in enumerate(rates))
        (run / "eval.csv").write_text("step,wall_s,episodes,success\n" + rows)
        runs.append(run)
        (run / "config.json").write_text(json.dumps({"algo": "dqn", "total_steps": 1000, "seed": seed}))
    assert script.best_run(runs) == runs[1]  # a tie goes to the first
    assert script.best_run([runs[0], runs[2]]) == runs[2]
    (runs[2] / "config.json").write_text(json.dumps({"algo": "dqn", "total_steps": 500, "seed": 2}))
    with pytest.raises(SystemExit, match="differ in more than their seed \\(total_steps\\)"):
        script.best_run(runs)  # another budget's run is refused, not compared
    (runs[2] / "config.json").write_text(json.dumps({"algo": "dqn", "total_steps": 1000, "seed": 2}))
    (runs[0] / "eval.csv").write_text("step,wall_s,episodes,success\n")
    with pytest.raises(SystemExit, match="no periodic evaluation"):
        script.best_run(runs)


def test_project_table_is_rewritten_between_its_markers_and_nowhere_else(tmp_path, capsys):
    script = _train_shipped()
    start, end = script.README_MARKERS
    record = {"success": 0.905, "collision": 0.09, "timeout": 0.005, "off_surface": 0.0, "train_steps": 320_000,
              "train_wall_s": 3076.8, "seeds": [0, 1]}
    report = {"deck2": {"mddpg": record}}
    readme = tmp_path / "README.md"
    readme.write_text(f"intro\n{start}\n| old | row |\n{end}\noutro\n", encoding="utf-8")
    assert script.write_project_table(report, readme)
    once = readme.read_text(encoding="utf-8")
    assert once.startswith(f"intro\n{start}\n| scene | agent |") and once.endswith(f"{end}\noutro\n")
    assert ("| deck2 | MDDPG | oracle-teacher | 2 (seeds 0, 1; mean action) | 90.5 % | 9.0 % | "
            "0.5 % | 0.0 % | 320,000 | 51 min |") in once
    assert "old" not in once
    assert script.write_project_table(report, readme) and readme.read_text(encoding="utf-8") == once  # idempotent
    assert not (tmp_path / "README.md.tmp").exists()
    for broken in ("no markers\n", f"{end}\n{start}\n", f"{start}\n{end}\n{start}\n{end}\n"):
        readme.write_text(broken, encoding="utf-8")
        assert not script.write_project_table(report, readme)
        assert readme.read_text(encoding="utf-8") == broken  # left alone, and said so
        assert "was not updated" in capsys.readouterr().out


def test_several_runs_ship_as_one_ensemble_with_every_runs_log(tmp_path, monkeypatch):
    """``scripts/train_shipped.py`` with two seeds: the file is the runs' actors averaged, each run's log is kept
    (the first beside the file's name, the other in ``seed<k>/``), a stale log of an earlier ensemble goes, and
    the training time is the runs' sum."""
    from deck_sim.policies import registry, shipped_policy_path

    script = _train_shipped()
    actor = load_actor(shipped_policy_path("ddpg", "deck1"))
    actor = actor.members[0] if isinstance(actor, EnsemblePolicy) else actor
    runs = []
    for seed, wall in ((0, 600.0), (3, 900.0)):
        run = tmp_path / "runs" / f"deck1-tuned-ddpg-with-data+polish+size-seed{seed}"
        run.mkdir(parents=True)
        arrays = {k: (v * (1.0 + 0.01 * seed)).astype(v.dtype) if k.startswith("w") else v
                  for k, v in actor.arrays.items()}
        meta = {**actor.meta, "polished": True, "config": {**actor.meta["config"], "seed": seed}}
        write_actor_file(run / "actor.npz", arrays, meta, compress=False)
        (run / "eval.csv").write_text(f"step,wall_s,success\n1000,{wall / 2},0.5\n2000,{wall},0.7\n")
        (run / "config.json").write_text(json.dumps({"seed": seed}))
        runs.append(run)
    logs = tmp_path / "logs" / "deck1_ddpg"
    (logs / "seed9").mkdir(parents=True)
    (logs / "seed9" / "eval.csv").write_text("step,wall_s\n1,1\n")  # an earlier ensemble's third run
    monkeypatch.setattr(registry, "TRAINED_DIR", tmp_path)  # the shipped logs under tmp_path/logs
    dest = tmp_path / "deck1_ddpg.npz"
    script.ship(runs, dest)
    script.ship_logs(runs, (0, 3), "deck1", "ddpg")
    shipped = load_actor(dest)
    assert isinstance(shipped, EnsemblePolicy) and script.file_seeds(shipped.meta) == (0, 3)
    assert (logs / "eval.csv").read_text() == (runs[0] / "eval.csv").read_text()
    assert (logs / "seed3" / "config.json").read_text() == (runs[1] / "config.json").read_text()
    assert not (logs / "seed9").exists()
    assert shipped_logs("ddpg", "deck1") == [(logs, 0), (logs / "seed3", 3)]
    assert sum(script._train_wall(d) for d, _ in shipped_logs("ddpg", "deck1")) == 1500.0
    (logs / "seed3" / "config.json").write_text("{")  # an unreadable config: the folder stays, its seed unknown
    (logs / "seed5").mkdir()  # a folder without a log is not a run's
    assert shipped_logs("ddpg", "deck1") == [(logs, 0), (logs / "seed3", None)]
    script.ship(runs[:1], dest)  # one run: its actor file itself
    assert dest.read_bytes() == (runs[0] / "actor.npz").read_bytes()
    assert script.file_seeds(load_actor(dest).meta) == (0,)
    assert not list(tmp_path.glob("*.tmp*"))


def test_a_shipped_agent_gains_seeds_without_its_earlier_run_folders(tmp_path, monkeypatch, capsys):
    """``scripts/train_shipped.py`` on a checkout without the run folders of a shipped MDDPG: each seed whose actor
    the shipped file holds, trained with the recipe's configuration, is taken from the file with its shipped logs
    (not trained again); a seed with a run folder here, or trained with another budget, is not."""
    from deck_sim.policies import registry, shipped_policy_path

    script = _train_shipped()
    shipped = shipped_policy_path("mddpg-reward", "deck1")
    members = script.shipped_members(shipped)
    assert sorted(members) == [0, 1, 2]
    steps = script.default_steps("deck1", "mddpg-reward")
    runs = [script.run_folder(tmp_path / "runs", "deck1", "mddpg-reward", s) for s in (0, 1, 2)]
    kept = script.kept_seeds(shipped, "deck1", "mddpg-reward", steps, (0, 1, 2), runs, {})
    assert sorted(kept) == [0, 1, 2]  # the shipped actors are what the recipe trains for these seeds
    runs[1].mkdir(parents=True)
    (runs[1] / "checkpoint.pt").write_bytes(b"")  # a run under way here is resumed, not replaced
    assert sorted(script.kept_seeds(shipped, "deck1", "mddpg-reward", steps, (0, 1, 2), runs, {})) == [0, 2]
    assert script.kept_seeds(shipped, "deck1", "mddpg-reward", steps // 2, (0, 2), [runs[0], runs[2]], {}) == {}
    assert "seed 0 was trained with other total_steps" in capsys.readouterr().out

    # the shipped logs of the kept seeds survive ship_logs' clearing of the logs folder
    monkeypatch.setattr(registry, "TRAINED_DIR", tmp_path / "trained")
    logs = tmp_path / "trained" / "logs" / "deck1_mddpg-reward"
    shutil.copytree(shipped.parent / "logs" / "deck1_mddpg-reward", logs)
    before = {s: (f / "eval.csv").read_text() for f, s in shipped_logs("mddpg-reward", "deck1")}
    assert sorted(before) == [0, 1, 2]
    staged = script.stage_shipped_logs("deck1", "mddpg-reward", {0, 2}, tmp_path / "staging")
    assert sorted(staged) == [0, 2] and not list(staged[0].glob("seed*"))
    new_run = tmp_path / "runs" / "deck1-reward-mddpg-seed3"
    new_run.mkdir()
    (new_run / "eval.csv").write_text("step,wall_s,success\n1000,60,0.5\n")
    (new_run / "config.json").write_text(json.dumps({"seed": 3}))
    script.ship_logs([staged[0], new_run, staged[2]], (0, 3, 2), "deck1", "mddpg-reward")
    after = dict((s, f) for f, s in shipped_logs("mddpg-reward", "deck1"))
    assert sorted(after) == [0, 2, 3] and after[0] == logs
    assert (after[0] / "eval.csv").read_text() == before[0] and (after[2] / "eval.csv").read_text() == before[2]

    # the file: the kept members as they were, alone or joined
    dest = tmp_path / "deck1_mddpg-reward.npz"
    script.ship([members[0], members[2]], dest)
    joined = load_actor(dest)
    assert isinstance(joined, EnsemblePolicy) and script.file_seeds(joined.meta) == (0, 2)
    script.ship([members[1]], dest)
    alone = load_actor(dest)
    assert isinstance(alone, LearnedPolicy) and script.file_seeds(alone.meta) == (1,)
    env = deck_sim.load("deck1", seed=3, **alone.scene_overrides)
    observation = env.reset().observation
    np.testing.assert_array_equal(alone.act(observation), members[1].act(observation))
    assert not list(tmp_path.glob("*.tmp*"))


def test_train_shipped_adds_seeds_to_a_shipped_agent_and_skips_complete_ones(tmp_path, monkeypatch, capsys):
    """The whole command on a checkout without run folders: MDDPG shipped with seed 0 gains seed 2 (trained here;
    seed 0 taken from the file, not trained again, its logs kept), and DQN shipped from seeds 0 and 2 gains seed 1
    (the kept seeds' logs compete again, the shipped run stays the best); agents shipped with all their recipe's
    seeds (MDDPG's three, DQN's chosen run of three) are skipped, and a shipped ensemble is not cut down to
    other seeds without ``--redo``."""
    import sys

    from deck_sim.policies import registry

    script = _train_shipped()
    trained = tmp_path / "trained"
    (trained / "logs").mkdir(parents=True)
    for algo in ("mddpg-reward", "dqn-reward"):
        shutil.copyfile(registry.TRAINED_DIR / f"deck1_{algo}.npz", trained / f"deck1_{algo}.npz")
        shutil.copytree(registry.TRAINED_DIR / "logs" / f"deck1_{algo}", trained / "logs" / f"deck1_{algo}")
    report = json.loads((registry.TRAINED_DIR / "results.json").read_text())
    (trained / "results.json").write_text(json.dumps({"deck1": {a: report["deck1"][a]
                                                                for a in ("mddpg-reward", "dqn-reward")}}))
    monkeypatch.setattr(registry, "TRAINED_DIR", trained)
    monkeypatch.setattr(script, "TRAINED_DIR", trained)
    monkeypatch.setattr(script, "write_readme", lambda report: None)
    monkeypatch.setattr(script, "held_out_record", lambda run, episodes, play="shipped": None)
    members = script.shipped_members(trained / "deck1_mddpg-reward.npz")
    source = tmp_path / "source"  # the runs' logs as shipped, where the fake training finds them
    for algo in ("mddpg-reward", "dqn-reward"):
        shutil.copytree(trained / "logs" / f"deck1_{algo}", source / algo)
    mddpg = source / "mddpg-reward"
    source_logs = {0: mddpg, 1: mddpg / "seed1", 2: mddpg / "seed2"}
    dqn_logs = {0: source / "dqn-reward" / "seed0", 1: source / "dqn-reward" / "seed1", 2: source / "dqn-reward"}
    dqn = load_actor(trained / "deck1_dqn-reward.npz")
    dqn_actor = tmp_path / "dqn.npz"  # seed 1's stand-in: the shipped run's actor, its weights scaled
    write_actor_file(dqn_actor, {k: v * 1.01 if k.startswith("w") else v for k, v in dqn.arrays.items()},
                     {**dqn.meta, "config": {**dqn.meta["config"], "seed": 1}}, compress=False)
    seed1_best = [None]  # a best periodic evaluation for seed 1 other than its shipped log's
    calls = []

    def fake_train(run, scene, algo, steps, seed, fields):  # a finished run of that seed, as training leaves it
        calls.append((algo, seed))
        run.mkdir(parents=True)
        if algo == "dqn-reward":  # (the shipped run's actor stands in for this seed's)
            shutil.copyfile(dqn_actor, run / "actor_best.npz")
        else:
            member = members[seed]
            write_actor_file(run / "actor_best.npz", member.arrays, member.meta, compress=False)
        shutil.copyfile(run / "actor_best.npz", run / "actor.npz")
        logs = dqn_logs if algo == "dqn-reward" else source_logs
        for name in ("eval.csv", "config.json", "heldout_100.json"):
            shutil.copyfile(logs[seed] / name, run / name)
        if algo == "dqn-reward" and seed1_best[0] is not None:
            with open(run / "eval.csv", "a") as f:
                f.write(f"1000000,60000,100,{seed1_best[0]},0.0,0.0,0.0,0.0\n")

    monkeypatch.setattr(script, "train", fake_train)
    out = tmp_path / "runs"

    def main(*argv):
        monkeypatch.setattr(sys, "argv", ["train_shipped.py", "--scenes", "deck1", "--out", str(out), *argv])
        script.main()
        return capsys.readouterr().out

    said = main("--algos", "mddpg-reward,dqn-reward")
    assert said.count("shipped and measured already") == 2 and calls == []
    said = main("--algos", "mddpg-reward", "--seeds", "0,3")  # not a superset of the file's seeds 0, 1, 2
    assert "shipped and measured already" in said and calls == []

    script.ship([members[0]], trained / "deck1_mddpg-reward.npz")  # as shipped with --seeds 0
    script.ship_logs([source_logs[0]], (0,), "deck1", "mddpg-reward")
    seed0 = (trained / "logs" / "deck1_mddpg-reward" / "eval.csv").read_text()
    said = main("--algos", "mddpg-reward", "--seeds", "0,2", "--episodes", "2")
    assert calls == [("mddpg-reward", 2)]  # seed 0 came from the shipped file
    assert "seed 0 as shipped with deck1_mddpg-reward.npz" in said
    shipped = load_actor(trained / "deck1_mddpg-reward.npz")
    assert isinstance(shipped, EnsemblePolicy) and script.file_seeds(shipped.meta) == (0, 2)
    logs = dict((s, f) for f, s in shipped_logs("mddpg-reward", "deck1"))
    assert sorted(logs) == [0, 2] and (logs[0] / "eval.csv").read_text() == seed0
    record = json.loads((trained / "results.json").read_text())["deck1"]["mddpg-reward"]
    assert record["seeds"] == [0, 2] and record["episodes"] == 2
    walls = [script._train_wall(source_logs[s]) for s in (0, 2)]
    assert record["train_wall_s"] == pytest.approx(sum(walls))
    assert not list(Path(tempfile.gettempdir()).glob("deck_sim-shipped-logs-deck1_mddpg-reward-*"))

    # DQN, shipped as the best of seeds 0 and 2, gains seed 1: the kept seeds' logs take part in the choice again,
    # and the shipped run (seed 2, the best of the three) stays
    script.ship_logs([dqn_logs[2], dqn_logs[0]], (2, 0), "deck1", "dqn-reward")
    with script.locked_report() as report:
        report["deck1"]["dqn-reward"]["trained_seeds"] = [0, 2]
    before = (trained / "deck1_dqn-reward.npz").read_bytes()
    calls.clear()
    said = main("--algos", "dqn-reward", "--seeds", "0,1,2", "--episodes", "2")
    assert calls == [("dqn-reward", 1)] and "seed 2 as shipped with deck1_dqn-reward.npz" in said
    assert (trained / "deck1_dqn-reward.npz").read_bytes() == before
    assert [s for _, s in shipped_logs("dqn-reward", "deck1")] == [2, 0, 1]
    record = json.loads((trained / "results.json").read_text())["deck1"]["dqn-reward"]
    assert record["seeds"] == [2] and record["trained_seeds"] == [0, 1, 2]

    def shipped_from_seeds_0_and_2():
        script.ship_logs([dqn_logs[2], dqn_logs[0]], (2, 0), "deck1", "dqn-reward")
        with script.locked_report() as report:
            report["deck1"]["dqn-reward"]["trained_seeds"] = [0, 2]
        shutil.rmtree(out / "deck1-reward-dqn-seed1")
        calls.clear()

    # a new run that beats the shipped one replaces it
    shipped_from_seeds_0_and_2()
    seed1_best[0] = 0.95
    main("--algos", "dqn-reward", "--seeds", "0,1,2", "--episodes", "2")
    assert calls == [("dqn-reward", 1)]
    assert (trained / "deck1_dqn-reward.npz").read_bytes() == (out / "deck1-reward-dqn-seed1" / "actor_best.npz"
                                                               ).read_bytes()
    assert [s for _, s in shipped_logs("dqn-reward", "deck1")] == [1, 0, 2]
    # a shipped file that is not the best kept run's actor is refused before anything trains
    shipped_from_seeds_0_and_2()
    staged_before = set(Path(tempfile.gettempdir()).glob("deck_sim-shipped-logs-deck1_dqn-reward-*"))
    with pytest.raises(SystemExit, match="is not the actor of seed 2, the best of the shipped runs"):
        main("--algos", "dqn-reward", "--seeds", "0,1,2", "--episodes", "2")
    assert calls == []
    # the kept seeds' staged logs stay, named, when shipping stops
    staged = set(Path(tempfile.gettempdir()).glob("deck_sim-shipped-logs-deck1_dqn-reward-*")) - staged_before
    assert len(staged) == 1 and "stopped; a copy of the shipped logs" in capsys.readouterr().out
    (folder,) = staged
    assert len(list(folder.rglob("eval.csv"))) == 2  # seeds 0 and 2
    shutil.rmtree(folder)
    # --evaluate-only measures the shipped file again, training nothing
    said = main("--algos", "mddpg-reward", "--evaluate-only", "--episodes", "1")
    assert calls == [] and "deck1 mddpg-reward: held-out success" in said
    record = json.loads((trained / "results.json").read_text())["deck1"]["mddpg-reward"]
    assert record["seeds"] == [0, 2] and record["episodes"] == 1


def test_an_ensemble_shipped_under_a_recipes_old_name_keeps_its_seeds_and_gets_them_measured(tmp_path, capsys):
    """The oracle-teacher MDDPG was trained when its recipe had another name (a note in its config the trainer never
    reads): ``scripts/train_shipped.py`` keeps its seeds (trains only the seeds it lacks), measures a kept seed
    whose shipped logs hold no held-out record so that its record ships with them, and joins the kept actors with
    a run of the current recipe into one ensemble; a run of another budget is refused by the field that differs."""
    from deck_sim.policies import shipped_policy_path
    from training.config import TrainConfig

    script = _train_shipped()
    shipped = shipped_policy_path("mddpg", "deck1")
    members = script.shipped_members(shipped)
    assert members[0].meta["config"]["extra"]["recipe"] != "deck1"  # (the name it was trained under)
    steps = script.default_steps("deck1", "mddpg")
    runs = [script.run_folder(tmp_path / "runs", "deck1", "mddpg", s) for s in (0, 1, 2, 3)]
    assert sorted(script.kept_seeds(shipped, "deck1", "mddpg", steps, (0, 1, 2, 3), runs, {})) == [0, 1, 2]

    staged = script.stage_shipped_logs("deck1", "mddpg", {0, 1}, tmp_path / "staging", episodes=2)
    assert "hold no heldout_2.json" in capsys.readouterr().out
    script.measure_kept({0: members[0]}, staged, 2, "deck1 mddpg")
    assert "deck1 mddpg: measuring the actor of seed 0 taken from the shipped file on 2 held-out episodes" in \
        capsys.readouterr().out
    record = json.loads((staged[0] / "heldout_2.json").read_text())
    assert record["episodes"] == 2 and len(record["goal_each"]) == 2 and record["actor"] == "actor.npz"
    assert not (staged[0] / "actor.npz").exists() and not (staged[1] / "heldout_2.json").exists()
    script.measure_kept({0: members[0]}, staged, 2, "deck1 mddpg")  # a valid record is kept, not measured again
    assert "measuring" not in capsys.readouterr().out
    (staged[0] / "heldout_2.json").write_text(json.dumps({**record, "goal_each": None}))  # an older record's form
    script.measure_kept({0: members[0]}, staged, 2, "deck1 mddpg")
    assert "measuring the actor of seed 0" in capsys.readouterr().out
    assert json.loads((staged[0] / "heldout_2.json").read_text())["goal_each"] == record["goal_each"]

    # a run of the current recipe: its whole config as the trainer writes it today, every newer field included
    config = TrainConfig.from_dict(members[1].meta["config"]).to_dict()
    new = {**members[1].meta, "config": {**config, "seed": 2, "extra": {"recipe": "deck1"}}}
    assert set(new["config"]) > set(members[0].meta["config"])
    dest = tmp_path / "deck1_mddpg.npz"
    script.ship([members[0], members[1], LearnedPolicy(members[1].arrays, new)], dest)
    assert script.file_seeds(load_actor(dest).meta) == (0, 1, 2)
    longer = {**new, "config": {**new["config"], "total_steps": 2 * steps}}
    with pytest.raises(SystemExit, match="differ in more than their seed \\(total_steps\\)"):
        script.ship([members[0], LearnedPolicy(members[1].arrays, longer)], dest)


def test_a_run_folder_of_another_configuration_is_refused_not_reused(tmp_path):
    """A finished run folder counts as the recipe's run only if its config is what the recipe gives now (its
    length aside): one trained with other fields stops the script with the folder and the fields named."""
    from training.recipes import load_recipe

    script = _train_shipped()
    steps = script.default_steps("deck1", "mddpg-reward")
    run = tmp_path / "deck1-reward-mddpg-seed0"
    run.mkdir()
    load_recipe("deck1-reward").run("mddpg", 0).save(run / "config.json")
    (run / "actor.npz").write_bytes(b"")  # finished: nothing to train
    script.train(run, "deck1", "mddpg-reward", steps, 0, {})
    script.train(run, "deck1", "mddpg-reward", 2 * steps, 0, {})  # (another length: --steps extends a run)
    config = json.loads((run / "config.json").read_text())
    (run / "config.json").write_text(json.dumps({**config, "scene_overrides": {"episode__near_steps": 4}}))
    with pytest.raises(SystemExit, match="deck1-reward-mddpg-seed0: a run trained with other scene_overrides than "
                                         "the recipe gives now; move it away"):
        script.train(run, "deck1", "mddpg-reward", steps, 0, {})


def test_an_agent_acting_through_its_critic_ships_each_runs_averaged_actor_selecting(tmp_path, monkeypatch, capsys):
    """``mddpg-reward-select``: the runs of ``mddpg-reward``, each its averaged actor choosing by its own critic,
    joined as an ensemble whose members select; its logs carry that play's held-out record; a recipe without an
    averaged actor is refused by name."""
    import sys

    from conftest import short_config

    from deck_sim.policies import registry
    from training.final_fit import SELECT_CANDIDATES, SELECT_SPREAD
    from training.heldout import held_out_file
    from training.loop import Trainer

    script = _train_shipped()
    runs = []
    for seed in (0, 1):
        run = tmp_path / f"run{seed}"
        cfg = short_config(algo="ddpg", total_steps=80, seed=seed, demo_episodes=0, pretrain_updates=0,
                           bc_weight=0.0, expert_relabel=False, actor_average=1e-3)
        trainer = Trainer(cfg, run, progress=False)
        trainer.train()
        trainer.close()
        runs.append(run)
    dest = tmp_path / "deck1_ddpg-reward-select.npz"
    script.ship(runs, dest, script.play_of("ddpg-reward-select"))
    shipped = load_actor(dest)
    assert isinstance(shipped, EnsemblePolicy) and script.file_seeds(shipped.meta) == (0, 1)
    for member, run in zip(shipped.members, runs, strict=True):
        averaged = LearnedPolicy.load(run / "actor_avg.npz")
        assert member.selects and member.meta["select"]["candidates"] == SELECT_CANDIDATES
        assert member.meta["select"]["spread"] == SELECT_SPREAD
        assert all(np.array_equal(member.arrays[k], v) for k, v in averaged.arrays.items())
    script.ship(runs[:1], dest, "shipped")  # the plain agent: the run's own shipped actor, no selection
    assert not load_actor(dest).selects
    assert script.play_of("mddpg-reward") == "shipped" and script.play_of("dqn-reward") == "shipped"

    # the logs: each run's record of that play (not the plain one's)
    monkeypatch.setattr(registry, "TRAINED_DIR", tmp_path / "trained")
    for run in runs:
        (run / held_out_file(2, "averaged-select")).write_text("{}")
        (run / held_out_file(2)).write_text("{}")
    logs = script.ship_logs(runs, (0, 1), "deck1", "ddpg-reward-select", 2)
    assert (logs / held_out_file(2, "averaged-select")).exists() and not (logs / held_out_file(2)).exists()
    assert (logs / "seed1" / held_out_file(2, "averaged-select")).exists()

    monkeypatch.setattr(sys, "argv", ["train_shipped.py", "--scenes", "deck1", "--algos", "mddpg-reward-select",
                                      "--out", str(tmp_path / "runs")])
    with pytest.raises(SystemExit, match="deck1 mddpg-reward-select: training/recipes/deck1-reward.toml keeps no "
                                         r"averaged actor \(actor_average\), which mddpg-reward-select acts through"):
        script.main()


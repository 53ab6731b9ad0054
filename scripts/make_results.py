"""Generate ``docs/results.md``: the task-suite evaluation of every agent on every scene, beside the paper's tables.

    python scripts/make_results.py [--episodes 100] [--workers 2] [--agents ...] [--scenes ...] [--out runs/results]

Runs ``deck_sim.evaluation`` (the engine of ``deck-sim eval``) on held-out episodes seeded 100000 + i, writes its
full report (JSON, CSV, Markdown, MCAP logs of the first two episodes of every scene and agent) to ``--out``, and
then ``docs/results.md`` with: the command and commit it came from, the machine, how many training seeds and
episodes stand behind each number (training figures from ``deck_sim/trained/results.json``), the tables, the
issue's targets checked against the numbers, learning curves from the training runs' ``eval.csv`` logs (the
``runs/learning`` folders ``scripts/train_shipped.py`` trains in, where present) and one trajectory plot per
scene. Nothing in ``docs/results.md`` is typed by hand.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MUJOCO_GL", "disable")

import argparse  # noqa: E402
import csv  # noqa: E402
import hashlib  # noqa: E402
import json  # noqa: E402
import shutil  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import asdict  # noqa: E402
from pathlib import Path  # noqa: E402

from deck_sim.agents import LEARNED  # noqa: E402
from deck_sim.evaluation import (  # noqa: E402
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
from deck_sim.policies import TRAINED_DIR, load_actor, shipped_log_dir  # noqa: E402
from deck_sim.policies.regimes import actor_regime, regime_text  # noqa: E402
from deck_sim.progress import progress  # noqa: E402
from deck_sim.rollout import git_commit  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
AGENTS = "mddpg,ddpg,dqn,a2c,apf,astar,mpc,scripted,scripted-body"


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
            if agent in missing[scene]:
                lines.append(f"| {agent} | {scene} | - | no policy shipped yet: not evaluated (n/a) | - | - | 0 |")
            elif agent in LEARNED:
                fig = training_figures(scene, agent) or {}
                steps = f"{fig['train_steps']:,}" if "train_steps" in fig else "?"
                wall = f"{fig['train_wall_s'] / 60:.0f} min" if "train_wall_s" in fig else "?"
                seeds = fig.get("seeds") or [fig.get("seed", "?")]
                runs = (f"{len(seeds)} (seeds {', '.join(map(str, seeds))}; the mean of their actors' actions)"
                        if len(seeds) > 1 else f"1 (seed {seeds[0]})")
                learnt = shipped_regime(scene, agent) or "not recorded"
                lines.append(f"| {agent} | {scene} | {learnt} | {runs} | {steps} | {wall} | {episodes} |")
            else:
                lines.append(f"| {agent} | {scene} | - | none (no training) | - | - | {episodes} |")
    return lines


def shipped_regime(scene: str, agent: str) -> str | None:
    """The training regime recorded in the shipped actor file of ``agent`` on ``scene`` (None if not recorded)."""
    path = TRAINED_DIR / f"{scene}_{agent}.npz"
    return actor_regime(load_actor(path).meta) if path.exists() else None


def targets(res) -> list[str]:  # noqa: ANN001 - EvalResults
    """The paper's MDDPG figures beside ours. The paper's agents learnt from the reward alone; only an MDDPG of
    the ``reward`` regime is measured against them by its protocol, so each line names the shipped one's regime."""
    out = []
    for scene, goal in (("deck1", 0.98), ("deck2", 0.91)):
        try:
            m = res.summary(scene, "mddpg")
        except KeyError:
            continue
        regime = shipped_regime(scene, "mddpg")
        if regime == "reward":
            verdict = "met" if m["goal_rate"] >= goal else "not met"
        else:
            verdict = (
                f"not comparable: the shipped MDDPG learnt from {regime_text(regime)}, the paper's from the reward "
                "alone"
            )
        out.append(
            f"- MDDPG on {scene}: {100 * m['goal_rate']:.1f} % against the paper's {100 * goal:.0f} %: {verdict}."
        )
        try:
            d = res.summary(scene, "ddpg")
        except KeyError:
            continue
        ahead = "ahead of" if m["goal_rate"] > d["goal_rate"] else "not ahead of"
        overlap = m["goal_ci"][0] <= d["goal_ci"][1] and d["goal_ci"][0] <= m["goal_ci"][1]
        out.append(
            f"- MDDPG {ahead} DDPG without prediction on {scene}: {100 * m['goal_rate']:.1f} % against "
            f"{100 * d['goal_rate']:.1f} %" + (" (the 95 % intervals overlap)." if overlap else " (intervals apart).")
        )
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
                continue
            base = bar.n
            part = evaluate(cfg, progress=lambda done, total, batch, base=base: bar.update(base + done - bar.n))
            write_report(part, cache)
            (cache / "fingerprint.json").write_text(json.dumps({"key": key, "logs": part.logs, "wall_s": part.wall_s}))
            parts.append(part)
    res = EvalResults.merge(parts)
    cfg = res.config
    write_report(res, args.out)
    figures = Path(args.doc).parent / "results"
    figures.mkdir(parents=True, exist_ok=True)
    curve_lines = []
    for scene in scenes:
        runs = {}
        for agent in agents:
            if agent in LEARNED:
                run = Path(args.runs) / f"{scene}-{agent}-seed0"  # scripts/train_shipped.py's run folder
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
                shown = run.relative_to(ROOT) if run.is_absolute() and run.is_relative_to(ROOT) else run
                others = sorted(d.name for d in run.glob("seed*") if (d / "eval.csv").exists())
                also = (f" (seed {c.get('seed', 0)}'s run; the shipped ensemble's other runs: "
                        f"{', '.join(f'`{o}/eval.csv`' for o in others)})") if others else ""
                how.append(f"{agent}: `{shown}/eval.csv`{also}, {'/'.join(episodes)} episodes of {stream} per point")
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
        f"`{commit}`, {machine()}; {res.wall_s / 60:.1f} min of evaluation "
        f"({cfg.backend} backend). Do not edit by hand: rerun the command.",
        "",
        "Agents: the four learned policies shipped in `deck_sim/trained/` (MDDPG, DDPG without prediction, DQN, "
        "A2C; trained by `scripts/train_shipped.py`), the classical references of `deck_sim/control/planners.py` "
        "(APF, A* with replanning, CasADi MPC; they plan around the MPC predictor's forecast, the one MDDPG sees) "
        "and `scripted`, the full-knowledge planner that sees the movers' true future (the solvability ceiling); "
        "`scripted-body` is the same planner checking the aircraft's nose and tail on the way its tracker will "
        "really take it (the teacher of the `body` recipes; on the square, whose walker is a disc, it is `scripted`).",
        "",
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
        *targets(res),
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

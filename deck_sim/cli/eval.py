"""``deck-sim eval``: the task-suite evaluation: agents x scenes on held-out episodes, tables, plots and logs."""

from __future__ import annotations

import argparse
from pathlib import Path

from deck_sim.cli._common import add_command
from deck_sim.progress import progress as progress_report


def cmd_eval(args: argparse.Namespace) -> int:
    """Evaluate every agent on every scene, print the tables and write the report, figures and logs."""
    from deck_sim.evaluation import EvalConfig, evaluate, plot_learning_curves, plot_trajectories, write_report

    split = [a.strip() for a in args.agents.split(",") if a.strip()]
    cfg = EvalConfig(
        agents=tuple(split),
        scenes=tuple(s.strip() for s in args.scenes.split(",") if s.strip()),
        episodes=args.episodes,
        seed=args.seed,
        backend=args.backend,
        workers=args.workers,
        ray_address=args.ray_address,
        chunk=args.chunk,
        record=args.record,
        out=args.out,
        near_miss=args.near_miss,
    )
    cfg.validate()
    curves = []
    for item in args.curves:  # checked before any episode runs
        label, _, run = item.partition("=")
        if not label or not run:
            raise ValueError(f"--curves {item!r}: expected LABEL=RUN_FOLDER")
        if not (Path(run) / "eval.csv").exists():
            raise ValueError(f"--curves {item!r}: {Path(run) / 'eval.csv'} does not exist (not a deck-sim train run)")
        curves.append((label, run))
    total = args.episodes * len(cfg.agents) * len(cfg.scenes)
    bar = progress_report(total=total, desc=f"eval ({cfg.backend})", unit="ep", disable=args.quiet)
    wins: dict[str, list[int]] = {}

    def progress(done: int, total: int, batch: list[dict]) -> None:
        bar.update(done - bar.n)
        for r in batch:
            w = wins.setdefault(f"{r['scene']}/{r['agent']}", [0, 0])
            w[0] += r["outcome"] == "goal"
            w[1] += 1
        key = f"{batch[-1]['scene']}/{batch[-1]['agent']}"
        bar.set_postfix({key: f"{100 * wins[key][0] / wins[key][1]:.0f}% of {wins[key][1]}"})

    with bar:
        res = evaluate(cfg, progress=progress)
    paths = write_report(res, args.out)
    print((Path(args.out) / "results.md").read_text())
    figures = plot_trajectories(res, Path(args.out) / "trajectories")
    if curves:
        figures.append(plot_learning_curves(dict(curves), Path(args.out) / "learning_curves.png"))
    print(f"{total} episodes in {res.wall_s:.1f} s ({cfg.backend}); wrote " + ", ".join(str(p) for p in paths.values()))
    if figures:
        print(f"figures: {', '.join(str(f) for f in figures)}")
    if res.config.record != "none":
        print(f"episode logs: {Path(args.out) / 'logs'} (deck-sim log info <file>, or open in Foxglove)")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``eval`` to the subcommands."""
    from deck_sim.agents import policy_help
    from deck_sim.evaluation import BACKENDS, DEFAULT_AGENTS, DEFAULT_SEED

    p = add_command(
        sub, "eval", cmd_eval, "task-suite evaluation: agents x scenes on held-out episodes, tables, plots and logs",
        "Every agent plays the same episodes (episode i of a scene is reset with seed --seed + i, below every\n"
        "training seed). The report in --out holds summary.json, summary.csv, episodes.csv and results.md (the\n"
        "paper's Tables 1-3 beside ours), trajectory plots and MCAP logs of the first --record episodes.",
    )
    p.add_argument("--agents", default=",".join(DEFAULT_AGENTS),
                   help="comma-separated agents, or label=actor.npz; " + policy_help())
    p.add_argument("--scenes", default="deck1,deck2,square", help="comma-separated scene names or TOML paths")
    p.add_argument("--episodes", type=int, default=100, help="episodes per scene and agent")
    p.add_argument("--seed", type=int, default=DEFAULT_SEED, help="seed of episode 0; episode i uses seed+i")
    p.add_argument("--backend", default="process", choices=BACKENDS,
                   help="process pool, serial, or ray (pip install 'deck-sim[ray]')")
    p.add_argument("--workers", type=int, default=None, help="worker processes / Ray CPUs (default: CPU count)")
    p.add_argument("--ray-address", default=None, help="address of an existing Ray cluster (default: start one)")
    p.add_argument("--chunk", type=int, default=5, help="episodes per work unit")
    p.add_argument("--record", default="2", help="episodes logged per scene and agent: all, none or N")
    p.add_argument("--near-miss", type=float, default=None, help="near-miss clearance, m (default: half the reach)")
    p.add_argument("--curves", action="append", default=[], metavar="LABEL=RUN_FOLDER",
                   help="plot learning curves from a deck-sim train run folder (repeatable)")
    p.add_argument("--out", default="runs/eval", help="results folder")
    p.add_argument("--quiet", action="store_true", help="no progress report")

"""The learning subcommands of ``deck-sim``: ``train`` and ``ensemble``.

``register`` adds them to the simulator's command line (``deck_sim.cli``) through the ``deck_sim.cli`` entry-point
group; training needs the ``train`` extra (torch, stable-baselines3, TensorBoard).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import re
import sys
from pathlib import Path
from typing import Any

from deck_sim import agents
from deck_sim.cli._common import add_command, parse_assignments


def _require_training(algo: str) -> None:
    """Raise ``ValueError`` with the install command if a package of the ``train`` extra that ``algo`` needs is
    missing (the CLI turns it into exit code 2 before anything is written)."""
    needed = ["torch", "tensorboard"] + (["stable_baselines3"] if agents.AGENTS[algo].trainer == "sb3" else [])
    missing = [name for name in needed if importlib.util.find_spec(name) is None]
    if missing:
        raise ValueError(
            f"training {algo} needs {', '.join(missing)} (the train extra): pip install torch==2.13.0 && "
            "pip install -e '.[train]' (torch 2.13.0 first: an unpinned torch may pull a CUDA build of several GB)"
        )


def cmd_train(args: argparse.Namespace) -> int:
    """Train an agent into a run folder (or continue one with ``--resume``) and print its held-out figures."""
    _require_training(args.algo)
    from training.config import ConfigError
    from training.loop import CheckpointError

    try:
        out, config, baseline = _plan_run(args)
        if args.print_config:
            if config is not None:
                shown = config.to_dict()
            else:  # the config train_baseline will build from these keywords
                from training.baseline_config import baseline_config

                fields = {k: v for k, v in baseline.items() if k not in ("algo", "steps")}
                if baseline["steps"] is not None:
                    fields["total_steps"] = baseline["steps"]
                shown = baseline_config(args.algo, **fields).to_dict()
            print(json.dumps(shown, indent=2, sort_keys=True))
            return 0
        if config is not None:
            from training.loop import Trainer

            summary = Trainer(config, out, resume=args.resume, progress=not args.quiet).train()
        else:
            from training.baselines import train_baseline

            summary = train_baseline(**baseline, out=out, resume=args.resume, progress=not args.quiet)
    except (ConfigError, CheckpointError) as err:
        print(f"deck-sim train: error: {err}", file=sys.stderr)
        return 2
    ev = summary.get("eval") or {}
    scene = config.scene if config is not None else baseline["scene"]
    if ev:
        print(
            f"{args.algo} on {scene}: {summary['step']} steps in {summary['wall_s']:.0f} s; held-out "
            f"success {100 * ev['goal_rate']:.1f} %, collision {100 * ev['collision_rate']:.1f} %, "
            f"timeout {100 * ev['timeout_rate']:.1f} %, mean reward {ev['mean_reward']:.1f}"
        )
    if summary.get("stopped"):
        print(f"stopped at step {summary['step']}; continue with: deck-sim train --algo {args.algo} "
              f"--out {out} --resume")
    actor = "exported actor actor.npz" if (out / "actor.npz").exists() else "no actor yet (the run is not finished)"
    print(f"wrote {out} (config.json, progress.csv, eval.csv, tb/, checkpoint; {actor})")
    return 0


def cmd_ensemble(args: argparse.Namespace) -> int:
    """Write one actor file whose policy acts by the mean action of the given actors."""
    from deck_sim.policies import EnsemblePolicy, load_actor

    out = Path(args.out)
    if any(Path(a).resolve() == out.resolve() for a in args.actors):
        raise ValueError(f"--out {out} is one of the actors it would be made of; write the ensemble elsewhere")
    members = []
    for a in args.actors:  # an ensemble file given joins by its members: the result is flat, each actor weighs one
        policy = load_actor(a)
        members += policy.members if isinstance(policy, EnsemblePolicy) else [policy]
    ensemble = EnsemblePolicy(members, source=str(out))
    ensemble.save(out)
    meta = ensemble.meta
    print(f"wrote {out}: {len(ensemble.members)} {meta.get('algo', '?')} actors of scene {meta.get('scene', '?')!r} "
          f"(predictor {ensemble.predictor}), acting by their mean action; {out.stat().st_size / 1024:.0f} KiB")
    return 0


def _plan_run(args: argparse.Namespace) -> tuple[Path, Any, dict[str, Any] | None]:
    """The run folder and what to train there: a ``TrainConfig`` (MDDPG, DDPG) or the keyword arguments of
    ``train_baseline`` (DQN, A2C), from ``--recipe`` or ``--scene``/``--preset``, then ``--steps`` and ``--set``."""
    from training.config import ConfigError, TrainConfig, make_config

    recipe = None
    if args.recipe is not None:
        from training.recipes import load_recipe

        clash = [flag for flag, value in (("--scene", args.scene), ("--preset", args.preset)) if value is not None]
        if clash:
            raise ConfigError(f"--recipe {args.recipe} sets the scene and the preset; drop {' and '.join(clash)}")
        recipe = load_recipe(args.recipe)
    scene = recipe.scene if recipe is not None else args.scene or "deck1"
    label = recipe.name if recipe is not None else Path(scene).stem
    out = Path(args.out) if args.out else Path("runs") / f"train-{args.algo}-{label}-seed{args.seed}"
    changes = parse_assignments(args.set)
    flags = sorted({"algo", "scene", "seed", "steps", "total_steps"} & set(changes))
    if flags:
        flag = "steps" if flags[0] == "total_steps" else flags[0]
        raise ConfigError(f"--set {flags[0]}=...: use --{flag}")
    if agents.AGENTS[args.algo].trainer == "sb3":
        baseline = recipe.baseline_kwargs(args.algo) if recipe is not None else {"steps": None}
        if args.steps is not None:
            baseline["steps"] = args.steps
        return out, None, {"algo": args.algo, "scene": scene, "seed": args.seed, **baseline, **changes}
    if args.resume:
        from training.loop import RESUMABLE_CHANGES, config_from_checkpoint

        config = config_from_checkpoint(out)
        if args.steps is not None:
            config.total_steps = int(args.steps)
        fixed = sorted(set(changes) - set(RESUMABLE_CHANGES))
        if fixed:
            raise ConfigError(
                f"--resume keeps the run's config; --set may change only {', '.join(RESUMABLE_CHANGES)}, "
                f"not {', '.join(fixed)}"
            )
        return out, TrainConfig.from_dict({**config.to_dict(), **changes}), None
    if args.steps is not None:
        changes["total_steps"] = args.steps
    if recipe is not None:
        return out, recipe.config(args.algo, args.seed, **changes), None
    return out, make_config(args.preset or "tuned", algo=args.algo, scene=scene, seed=args.seed, **changes), None


def config_fields_help(width: int = 118) -> str:
    """The ``TrainConfig`` fields that ``--set`` takes, one line each: name, type, default and what it does."""
    import dataclasses
    import textwrap

    from training.config import TrainConfig, field_docs

    docs = field_docs(TrainConfig)
    defaults = TrainConfig().to_dict()
    lines = ["TrainConfig fields for --set FIELD=VALUE (MDDPG and DDPG; values read as JSON):"]
    for f in dataclasses.fields(TrainConfig):
        first = re.split(r"\.\s+(?=[A-Z])", docs.get(f.name, ""), maxsplit=1)[0].rstrip(".")
        head = f"  {f.name} ({f.type}, default {json.dumps(defaults[f.name])}): "
        lines += textwrap.wrap(first, width, initial_indent=head, subsequent_indent=" " * 6) or [head.rstrip(": ")]
    return "\n".join(lines)


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``train`` and ``ensemble`` to ``deck-sim``'s subcommands."""
    p = add_command(
        sub, "train", cmd_train, "train an agent (mddpg, ddpg; dqn, a2c through stable-baselines3)",
        "A run folder holds config.json, progress.csv, eval.csv, TensorBoard curves (tb/), an atomic checkpoint and\n"
        "the actor (actor.npz, actor_best.npz). Ctrl-C stops at a checkpoint; --resume continues exactly.",
    )
    p.epilog = config_fields_help()
    p.add_argument("--algo", default="mddpg", choices=agents.LEARNED, help="the agent to train")
    p.add_argument("--recipe", default=None,
                   help="a shipped recipe (deck1, deck2, square: the runs behind deck_sim/trained) or a recipe "
                        "TOML file; it sets the scene, the preset and every field the recipe names")
    p.add_argument("--scene", default=None, help="scene name or TOML path (default: deck1, or the recipe's)")
    p.add_argument("--steps", type=int, default=None, help="environment steps (default: the recipe's or preset's)")
    p.add_argument("--seed", type=int, default=0, help="seeds the networks, noise and training episodes")
    p.add_argument("--preset", default=None,
                   help="tuned (the switches that pay) or paper (plain DDPG); default tuned, or the recipe's")
    p.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                   help="override a TrainConfig field, e.g. --set twin_critics=false --set hidden=[128,128]")
    p.add_argument("--out", default=None, help="run folder (default: runs/train-<algo>-<scene>-seed<seed>)")
    p.add_argument("--resume", action="store_true", help="continue the run in --out from its checkpoint")
    p.add_argument("--quiet", action="store_true", help="no progress report")
    p.add_argument("--print-config", action="store_true",
                   help="print the run's full configuration as JSON and exit without training")

    p = add_command(sub, "ensemble", cmd_ensemble, "join actor files into one policy that acts by their mean action")
    p.add_argument("actors", nargs="+", help="actor .npz files (deck-sim train's actor.npz; an ensemble file adds its "
                                             "actors), two or more actors of one observation and scene fields")
    p.add_argument("--out", required=True, help="the ensemble .npz to write (an existing file is replaced)")

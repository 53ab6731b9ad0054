"""The learning subcommands of ``deck-sim``: ``train``, ``ensemble`` and ``select``.

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
    out = _run_folder(args)
    _require_training(args.algo or (_recorded_algo(out) if args.resume else None) or "mddpg")
    from training.config import ConfigError
    from training.loop import CheckpointError

    _check_backend(args)
    try:
        config, baseline = _plan_run(args, out)
        if baseline is not None and (args.backend != "local" or args.workers is not None):
            raise ConfigError(f"--backend and --workers apply to mddpg and ddpg, not to {baseline['algo']}")
        if args.print_config:
            if config is not None:
                shown = {**config.to_dict(), "regime": config.regime}
            else:  # the config train_baseline will build from these keywords
                from training.baseline_config import baseline_config

                fields = {k: v for k, v in baseline.items() if k not in ("algo", "steps")}
                if baseline["steps"] is not None:
                    fields["total_steps"] = baseline["steps"]
                shown = baseline_config(baseline["algo"], **fields).to_dict()
            print(json.dumps(shown, indent=2, sort_keys=True))
            return 0
        if config is not None:
            from training.team import make_trainer

            trainer = make_trainer(config, out, resume=args.resume, progress=not args.quiet, backend=args.backend,
                                   workers=args.workers, ray_address=args.ray_address)
            try:
                summary = trainer.train()
            finally:
                trainer.close()
        else:
            from training.baselines import train_baseline

            summary = train_baseline(**baseline, out=out, resume=args.resume, progress=not args.quiet)
    except (ConfigError, CheckpointError) as err:
        print(f"deck-sim train: error: {err}", file=sys.stderr)
        return 2
    ev = summary.get("eval") or {}
    algo, scene = (config.algo, config.scene) if config is not None else (baseline["algo"], baseline["scene"])
    if ev:
        print(
            f"{algo} on {scene}: {summary['step']} steps in {summary['wall_s']:.0f} s; held-out "
            f"success {100 * ev['goal_rate']:.1f} %, collision {100 * ev['collision_rate']:.1f} %, "
            f"timeout {100 * ev['timeout_rate']:.1f} %, mean reward {ev['mean_reward']:.1f}"
        )
    if summary.get("stopped"):
        print(f"stopped at step {summary['step']}; continue with: deck-sim train --out {out} --resume")
    actor = "exported actor actor.npz" if (out / "actor.npz").exists() else "no actor yet (the run is not finished)"
    print(f"wrote {out} (config.json, progress.csv, eval.csv, tb/, checkpoint; {actor})")
    return 0


def _check_backend(args: argparse.Namespace) -> None:
    """Refuse, before anything is written, a worker count below 1, a Ray address without the Ray backend, the Ray
    backend without Ray installed, and a Ray address where no cluster answers (``ValueError``, one line)."""
    if args.workers is not None and args.workers < 1:
        raise ValueError(f"--workers must be at least 1, got {args.workers}")
    if args.ray_address is not None and args.backend != "ray":
        raise ValueError("--ray-address needs --backend ray")
    if args.backend == "ray":
        from training.ray_backend import require_ray

        require_ray()
        if args.ray_address:
            from deck_sim.evaluation.harness import check_ray_address

            check_ray_address(args.ray_address)


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


def cmd_select(args: argparse.Namespace) -> int:
    """Write an actor file whose policy selects its actions by the critic it carries."""
    from deck_sim.policies import load_actor, selecting

    source, out = Path(args.source), Path(args.out)
    if source.resolve() == out.resolve():
        raise ValueError(f"--out {out} is the source; write the selecting actor elsewhere")
    if source.is_dir():  # a run folder: the actor and critic of its checkpoint, as the run last saved them
        from training.checkpoints import checkpoint_policy

        policy = checkpoint_policy(source, averaged=args.averaged)
        what = (f"the {'averaged ' if args.averaged else ''}actor and critic of {source}'s checkpoint at step "
                f"{policy.meta['trained_steps']:,}")
    elif args.averaged:
        raise ValueError(f"--averaged takes a run folder, not an actor file ({source}); the averaged actor's own file "
                         "is actor_avg.npz")
    else:
        policy = load_actor(source)
        what = str(source)
    chosen = selecting(policy, args.candidates, args.spread, args.seed)
    chosen.save(out)
    print(f"wrote {out}: {what}, selecting each action by its critic among the actor's and {args.candidates} "
          f"candidates around it (spread {args.spread}); {out.stat().st_size / 1024:.0f} KiB")
    return 0


def _run_folder(args: argparse.Namespace) -> Path:
    """``--out``, or ``runs/train-<algo>-<recipe or scene>-seed<seed>`` of the options given (mddpg, deck1 and seed 0
    where they are not)."""
    if args.out:
        return Path(args.out)
    label = Path(args.recipe).stem if args.recipe is not None else Path(args.scene or "deck1").stem
    seed = 0 if args.seed is None else args.seed
    return Path("runs") / f"train-{args.algo or 'mddpg'}-{label}-seed{seed}"


def _recorded_algo(out: Path) -> str | None:
    """The agent of the stable-baselines3 run in ``out`` as its ``config.json`` records it; None for any other folder
    (a DDPG run's agent, mddpg or ddpg, which need the same packages, is read from its checkpoint)."""
    if not (out / "model.zip").exists():
        return None
    try:
        algo = json.loads((out / "config.json").read_text()).get("algo")
    except (OSError, ValueError, AttributeError):
        return None  # the resume names what is wrong with the file
    return algo if algo in agents.ALGOS else None


def _plan_run(args: argparse.Namespace, out: Path) -> tuple[Any, dict[str, Any] | None]:
    """What to train in the run folder ``out``: a ``TrainConfig`` (MDDPG, DDPG) or the keyword arguments of
    ``train_baseline`` (DQN, A2C), from ``--recipe`` or ``--scene``/``--preset``, then ``--steps`` and ``--set``;
    with ``--resume``, the run's saved config (``_plan_resume``)."""
    from training.config import ConfigError, make_config

    recipe = None
    if args.recipe is not None:
        from training.recipes import load_recipe

        clash = [flag for flag, value in (("--scene", args.scene), ("--preset", args.preset)) if value is not None]
        if clash:
            raise ConfigError(f"--recipe {args.recipe} sets the scene and the preset; drop {' and '.join(clash)}")
        recipe = load_recipe(args.recipe)
    changes = parse_assignments(args.set)
    flags = sorted({"algo", "scene", "seed", "steps", "total_steps"} & set(changes))
    if flags:
        flag = "steps" if flags[0] == "total_steps" else flags[0]
        raise ConfigError(f"--set {flags[0]}=...: use --{flag}")
    if args.resume:
        return _plan_resume(args, out, recipe, changes)
    algo = args.algo or "mddpg"
    seed = 0 if args.seed is None else args.seed
    scene = recipe.scene if recipe is not None else args.scene or "deck1"
    if recipe is not None:
        plan = recipe.run(algo, seed, args.steps, **changes)
        return (None, plan) if isinstance(plan, dict) else (plan, None)
    if agents.AGENTS[algo].trainer == "sb3":
        return None, {"algo": algo, "scene": scene, "seed": seed, "steps": args.steps, **changes}
    if args.steps is not None:
        changes["total_steps"] = args.steps
    return make_config(args.preset or "tuned", algo=algo, scene=scene, seed=seed, **changes), None


def _plan_resume(
    args: argparse.Namespace, out: Path, recipe: Any, changes: dict[str, Any]
) -> tuple[Any, dict[str, Any] | None]:
    """The run in ``out`` as it was saved, with ``--steps`` and the ``--set`` fields a resumed run may change.
    ``--algo``, ``--scene``, ``--seed``, ``--preset`` and ``--recipe`` may be given only with the run's own values
    (``ConfigError`` naming each one that contradicts it), and ``--steps`` not below the steps the run has done,
    before anything is written."""
    from training.config import ConfigError, TrainConfig

    if (out / "model.zip").exists():  # a stable-baselines3 run
        from training.baselines import resume_config, saved_baseline_config

        saved = saved_baseline_config(out)
        _check_resume_options(args, recipe, out, {"algo": saved.algo, "scene": saved.scene, "seed": saved.seed,
                                                  "preset": None})
        fields = {**changes, **({} if args.steps is None else {"total_steps": args.steps})}
        cfg = resume_config(saved.algo, out, **fields).to_dict()
        keep = {k: v for k, v in cfg.items() if k not in ("algo", "total_steps")}
        return None, {"algo": cfg["algo"], "steps": cfg["total_steps"], **keep}
    from training.checkpoints import (
        CHECKPOINT,
        RESUMABLE_CHANGES,
        check_budget,
        checkpoint_config,
        comparable,
        load_run_checkpoint,
    )

    state = load_run_checkpoint(out)
    saved = comparable(state["config"])
    extra = saved.get("extra") if isinstance(saved.get("extra"), dict) else {}
    _check_resume_options(args, recipe, out, {"algo": saved.get("algo"), "scene": saved.get("scene"),
                                              "seed": saved.get("seed"), "preset": extra.get("preset"),
                                              "recipe": extra.get("recipe")})
    config = checkpoint_config(state, out / CHECKPOINT)
    fixed = sorted(set(changes) - set(RESUMABLE_CHANGES))
    if fixed:
        raise ConfigError(
            f"--resume keeps the run's config; --set may change only {', '.join(RESUMABLE_CHANGES)}, "
            f"not {', '.join(fixed)}"
        )
    if args.steps is not None:
        check_budget(args.steps, state, out / CHECKPOINT)
        config.total_steps = int(args.steps)
    return TrainConfig.from_dict({**config.to_dict(), **changes}), None


def _check_resume_options(args: argparse.Namespace, recipe: Any, out: Path, saved: dict[str, Any]) -> None:
    """``ConfigError`` naming each of ``--algo``, ``--scene``, ``--seed``, ``--preset`` and ``--recipe`` given with a
    value other than the run's (``saved``: its algo, scene, seed, preset and, where the run records it, recipe; a
    DQN or A2C run records no recipe, so ``--recipe`` must give its scene)."""
    from training.config import ConfigError

    given = [("--algo", "algo", args.algo), ("--scene", "scene", args.scene), ("--seed", "seed", args.seed),
             ("--preset", "preset", args.preset)]
    if recipe is not None:
        given.append(("--recipe", "recipe", recipe.name) if "recipe" in saved else ("--recipe", "scene", recipe.scene))
    wrong = [
        f"{flag} {args.recipe if flag == '--recipe' else value} (the run's {key}: {_shown(saved[key])})"
        for flag, key, value in given
        if value is not None and not _same(key, value, saved[key])
    ]
    if wrong:
        raise ConfigError(
            f"--resume continues the run in {out} as it was saved, and {', '.join(wrong)} "
            f"{'contradicts' if len(wrong) == 1 else 'contradict'} it: drop {'it' if len(wrong) == 1 else 'them'}"
        )


def _shown(value: Any) -> str:
    return "none" if value is None else str(value)


def _same(key: str, given: Any, saved: Any) -> bool:
    """Whether an option's value is the run's: scenes by name, or by file when both are paths to one file."""
    if given == saved:
        return True
    if key != "scene" or saved is None:
        return False
    a, b = Path(str(given)), Path(str(saved))
    return a.is_file() and b.is_file() and a.resolve() == b.resolve()


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
    """Add ``train``, ``ensemble`` and ``select`` to ``deck-sim``'s subcommands."""
    p = add_command(
        sub, "train", cmd_train, "train an agent (mddpg, ddpg; dqn, a2c through stable-baselines3)",
        "A run folder holds config.json, progress.csv, eval.csv, TensorBoard curves (tb/), an atomic checkpoint and\n"
        "the actor (actor.npz, actor_best.npz). Ctrl-C stops at a checkpoint; --resume continues exactly.",
    )
    p.epilog = config_fields_help()
    p.add_argument("--algo", default=None, choices=agents.ALGOS,
                   help="the agent to train (default: mddpg; with --resume, the run's)")
    # The files of training.recipes.recipe_names, read here without importing training.recipes (which imports the
    # configuration and policies), so that every deck-sim command starts as fast as before.
    shipped = ", ".join(sorted(f.stem for f in Path(__file__).with_name("recipes").glob("*.toml")))
    p.add_argument("--recipe", default=None,
                   help=f"a shipped recipe ({shipped}: <scene> the runs behind deck_sim/trained, taught by the "
                        "full-knowledge planner; <scene>-reward from the reward alone; <scene>-planner taught by the "
                        "planner on the agent's observation; deck1-multi one actor shared by four aircraft) or a "
                        "recipe TOML file; it sets the scene, the preset and every field the recipe names")
    p.add_argument("--scene", default=None, help="scene name or TOML path (default: deck1, or the recipe's)")
    p.add_argument("--steps", type=int, default=None, help="environment steps (default: the recipe's or preset's)")
    p.add_argument("--seed", type=int, default=None,
                   help="seeds the networks, noise and training episodes (default: 0; with --resume, the run's)")
    p.add_argument("--preset", default=None,
                   help="tuned (the switches that pay, with the full-knowledge teacher), reward (those switches "
                        "without the teacher) or paper (plain DDPG); default tuned, or the recipe's")
    p.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                   help="override a TrainConfig field, e.g. --set twin_critics=false --set hidden=[128,128]")
    p.add_argument("--out", default=None, help="run folder (default: runs/train-<algo>-<scene>-seed<seed>)")
    p.add_argument("--resume", action="store_true",
                   help="continue the run in --out from its checkpoint, with its saved config: --algo, --scene, "
                        "--seed, --preset and --recipe, if given, must be the run's; --steps may not be below "
                        "the steps done")
    p.add_argument("--backend", default="local", choices=("local", "ray"),
                   help="where the environments step: local (inline or worker processes, the default) or ray "
                        "(Ray actors; pip install 'deck-sim[ray]')")
    p.add_argument("--workers", type=int, default=None,
                   help="worker processes (local) or Ray actors (ray), each stepping and acting for a group of the "
                        "environments (default: the config's env_worker on local, 1 on ray, a resumed run's own); "
                        "runs with the same count give the same numbers on either backend")
    p.add_argument("--ray-address", default=None,
                   help="an existing Ray cluster (host:port or ray://host:port) for --backend ray; default: a local "
                        "Ray with --workers CPUs")
    p.add_argument("--quiet", action="store_true", help="no progress report")
    p.add_argument("--print-config", action="store_true",
                   help="print the run's full configuration as JSON and exit without training")

    p = add_command(sub, "ensemble", cmd_ensemble, "join actor files into one policy that acts by their mean action")
    p.add_argument("actors", nargs="+", help="actor .npz files (deck-sim train's actor.npz; an ensemble file adds its "
                                             "actors), two or more actors of one observation and scene fields")
    p.add_argument("--out", required=True, help="the ensemble .npz to write (an existing file is replaced)")

    p = add_command(
        sub, "select", cmd_select, "make an actor select its actions by its critic",
        "The actor proposes an action a; the critic rates a and clip(a + spread * z_j, -1, 1) for fixed unit-normal\n"
        "offsets z_j, and the policy takes the best (a on a tie). Every tool that plays actor files plays the\n"
        "written file this way (deck-sim run --policy, deck-sim eval --agents label=FILE).",
    )
    p.add_argument("source", help="an actor file that carries its critic (DDPG and MDDPG runs' actor.npz, "
                                  "actor_best.npz), or a run folder (the actor and critic of its checkpoint)")
    p.add_argument("--out", required=True, help="the actor .npz to write (an existing file is replaced)")
    p.add_argument("--candidates", type=int, default=64, help="candidates around the actor's action (default 64)")
    p.add_argument("--spread", type=float, default=0.3,
                   help="standard deviation of the candidates around the actor's action, action units (default 0.3)")
    p.add_argument("--seed", type=int, default=0, help="seed of the fixed offsets (default 0)")
    p.add_argument("--averaged", action="store_true",
                   help="with a run folder: its checkpoint's slow average of the actor (runs with actor_average)")

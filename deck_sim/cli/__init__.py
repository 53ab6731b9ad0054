"""``deck-sim``: the command line of deck_sim.

deck-sim scenes                                     list the scenes
deck-sim run --scene deck1 --policy mddpg --episodes 10 --seed 1000
                                                    play episodes, print and save the metrics and an episode log
deck-sim render --scene deck2 --out ep.mp4          a short video (offscreen) and a top-down PNG
deck-sim eval --agents mddpg,apf --scenes deck1     the task-suite evaluation: tables, plots, logs
deck-sim log info runs/deck1-mddpg-seed1000/episodes.mcap
                                                    read an episode log (also: log plot, log video, log export,
                                                    log recover)
deck-sim train --recipe deck1 --algo mddpg --seed 0 train an agent (with the train extra: pip install 'deck-sim[train]')
deck-sim ensemble A.npz B.npz --out AB.npz          join actors into one policy acting by their mean action

Every subcommand has its own --help.
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # offscreen rendering on a headless machine; set before mujoco loads

import argparse  # noqa: E402
import logging  # noqa: E402
import sys  # noqa: E402
from importlib.metadata import entry_points  # noqa: E402

from deck_sim.cli import eval as eval_command  # noqa: E402
from deck_sim.cli import log as log_command  # noqa: E402
from deck_sim.cli import render as render_command  # noqa: E402
from deck_sim.cli import run as run_command  # noqa: E402

PLUGIN_GROUP = "deck_sim.cli"
"""Entry-point group through which other packages add subcommands: each entry is a function
``register(subparsers)`` (the ``training`` package adds ``train`` and ``ensemble`` this way)."""


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``deck-sim``: the simulator's subcommands and those that plugins register."""
    from deck_sim import __version__

    parser = argparse.ArgumentParser(
        prog="deck-sim", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--version", action="version", version=f"deck-sim {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log diagnostics")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    run_command.register(sub)
    render_command.register(sub)
    eval_command.register(sub)
    log_command.register(sub)
    for plugin in sorted(entry_points(group=PLUGIN_GROUP), key=lambda e: e.name):
        plugin.load()(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``deck-sim``; returns the exit code (2 with a one-line message on bad input)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING, format="%(levelname)s %(name)s: %(message)s"
    )
    from deck_sim.scenes import SceneSpecError

    try:
        return int(args.func(args))
    except (SceneSpecError, ValueError, OSError) as err:
        print(f"deck-sim {args.command}: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())

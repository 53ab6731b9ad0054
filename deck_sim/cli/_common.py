"""Pieces shared by the subcommands of ``deck-sim``: the help layout and ``FIELD=VALUE`` arguments."""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

Command = Callable[[argparse.Namespace], int]
"""A subcommand's body: parsed arguments in, exit code out."""


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Keeps the description's line breaks and appends ``(default: X)`` to every option with a real default."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        default = action.default
        if (
            "%(default)" in text
            or default is None
            or default is False
            or default == []
            or default is argparse.SUPPRESS
            or not action.option_strings
        ):
            return text
        return f"{text} (default: %(default)s)"


def add_command(
    sub: argparse._SubParsersAction, name: str, func: Command, summary: str, description: str = ""
) -> argparse.ArgumentParser:
    """A subcommand parser whose ``--help`` opens with ``summary`` (and ``description``) and shows defaults."""
    text = summary[0].upper() + summary[1:] + "." + (f"\n\n{description}" if description else "")
    parser = sub.add_parser(name, help=summary, description=text, formatter_class=HelpFormatter)
    parser.set_defaults(func=func)
    return parser


def parse_assignments(items: list[str], flag: str = "--set") -> dict[str, object]:
    """``FIELD=VALUE`` pairs as a dict, values parsed as JSON where they can be, else kept as strings."""
    out: dict[str, object] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ValueError(f"{flag} expects field=value, got {item!r}")
        try:
            out[key.strip()] = json.loads(value)
        except json.JSONDecodeError:
            out[key.strip()] = value
    return out


def scene_overrides(items: list[str]) -> dict[str, object]:
    """``--scene-set section.field=value`` pairs as ``deck_sim.load`` overrides (``section__field``); the scene
    checks the names and values. A field given twice is refused (which value was meant is not for us to guess)."""
    from deck_sim.scenes import SECTIONS

    out: dict[str, object] = {}
    for item in items:
        ((key, value),) = parse_assignments([item], flag="--scene-set").items()
        section, dot, field = key.partition(".")
        if not dot or not section or not field:
            raise ValueError(f"--scene-set expects section.field=value (e.g. movers.yield_distance=12), got {key!r}")
        if section not in SECTIONS:
            raise ValueError(f"--scene-set {key}: no section [{section}]; the sections are {', '.join(SECTIONS)}")
        name = f"{section}__{field}"
        if name in out:
            raise ValueError(
                f"--scene-set {key} is given twice ({out[name]!r}, then {value!r}); give each field once"
            )
        out[name] = value
    return out


def policy_label(policy: str) -> str:
    """A policy's name for folder names (an actor file's stem)."""
    return Path(policy).stem if policy.endswith(".npz") else policy


def fmt(x: Any, spec: str) -> str:
    """``x`` formatted with ``spec``, or ``-`` for NaN (no value)."""
    return "-" if x != x else format(x, spec)


def refuse_multi_agent(command: str, scene: str, **overrides: object) -> None:
    """``ValueError`` if ``scene`` (with ``overrides``) puts several aircraft on the deck: ``deck-sim <command>``
    acts for one aircraft."""
    from deck_sim.scenes import load_scene

    spec = load_scene(scene, **overrides)
    if spec.multi_agent:
        raise ValueError(
            f"scene {spec.name!r} has {spec.agents.count} aircraft; deck-sim {command} acts for one. Play a "
            "multi-aircraft scene with deck-sim run, from Python (deck_sim.multiagent.parallel_env, "
            "deck_sim.policies.make_team_policy) or with benchmarks/multiagent.py"
        )


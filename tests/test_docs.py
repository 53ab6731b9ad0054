"""The documentation stays true to the product: every ``deck-sim`` command quoted in the README parses with the
real command line, every relative link and anchor in README.md and docs/ resolves, and no tracked text tells the
story of the project's making (numbered work sessions or issues, paths outside the repository)."""

from __future__ import annotations

import argparse
import re
import shlex
import subprocess
from pathlib import Path

import pytest

from deck_sim.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
HISTORY = re.compile(
    r"\bsessions? [0-9]+|earlier session[s]|\bissues? #?[0-9]+|earlier machin[e]"
    r"|\.\./shared/|shared/(reference|design)/",
    re.IGNORECASE,
)
"""Wording that tells the project's history rather than describing it."""
TEXT_SUFFIXES = {".md", ".py", ".toml", ".txt", ".cfg", ".ini", ".json", ".csv", ".xml", ".sh", ".yaml", ".yml", ""}


def readme_commands() -> tuple[list[str], list[str]]:
    """The ``deck-sim ...`` commands of README.md: whole command lines from its code blocks, and the inline code
    spans of its prose (which may leave out required arguments or stand for a value with ``<...>``)."""
    text = (ROOT / "README.md").read_text()
    blocks = []
    for block in re.findall(r"```[a-z]*\n(.*?)```", text, flags=re.S):
        for line in block.splitlines():
            for part in re.split(r"&&|;", line):
                part = part.split(" #", 1)[0].strip()
                match = re.search(r"(?:^|/)deck-sim (.*)$", part)
                if match:
                    blocks.append(match.group(1))
    prose = re.sub(r"```.*?```", "", text, flags=re.S)
    return blocks, re.findall(r"`deck-sim ([^`]*)`", prose)


def subcommand_parser(words: list[str]) -> tuple[argparse.ArgumentParser, list[str]]:
    """The (sub)parser that the leading subcommand words select, and the words after them."""
    parser = build_parser()
    while words:
        actions = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        if not actions or words[0] not in actions[0].choices:
            break
        parser, words = actions[0].choices[words[0]], words[1:]
    return parser, words


def test_the_readme_quotes_deck_sim_commands():
    blocks, inline = readme_commands()
    assert len(blocks) >= 5 and any(c.startswith("run ") for c in blocks)


@pytest.mark.parametrize("command", readme_commands()[0])
def test_every_readme_command_line_parses_with_the_real_cli(command, capsys):
    try:
        build_parser().parse_args(shlex.split(command))
    except SystemExit as exit_:
        pytest.fail(f"deck-sim {command}: the command line refuses it ({capsys.readouterr().err.strip()})"
                    if exit_.code else f"deck-sim {command}: prints help instead of running")


@pytest.mark.parametrize("command", readme_commands()[1])
def test_every_inline_command_names_a_real_subcommand_and_its_flags(command):
    words = shlex.split(command)
    parser, rest = subcommand_parser(words)
    assert parser.prog != "deck-sim" or command.startswith("--"), f"deck-sim {command}: no such subcommand"
    options = {s for a in parser._actions for s in a.option_strings}
    unknown = [w.split("=")[0] for w in rest if w.startswith("--") and w.split("=")[0] not in options]
    assert not unknown, f"deck-sim {command}: {parser.prog} has no option {', '.join(unknown)}"


def github_slug(heading: str) -> str:
    """The anchor GitHub gives a Markdown heading."""
    text = re.sub(r"[`*]|\[([^\]]*)\]\([^)]*\)", lambda m: m.group(1) or "", heading.strip()).lower()
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors(page: Path) -> set[str]:
    """Every heading anchor of a Markdown page (repeated headings get -1, -2, ... as on GitHub)."""
    seen: dict[str, int] = {}
    out = set()
    text = re.sub(r"```.*?```", "", page.read_text(), flags=re.S)
    for heading in re.findall(r"^#{1,6} (.+)$", text, flags=re.M):
        slug = github_slug(heading)
        n = seen.get(slug, 0)
        out.add(slug if n == 0 else f"{slug}-{n}")
        seen[slug] = n + 1
    return out


def links(page: Path) -> list[str]:
    text = re.sub(r"```.*?```", "", page.read_text(), flags=re.S)
    return re.findall(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)", text)


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_relative_link_and_anchor_resolves(page):
    broken = []
    for target in links(page):
        if re.match(r"[a-z]+:", target):  # http:, https:, mailto:
            continue
        path, _, anchor = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        if not dest.exists():
            broken.append(f"{target}: no file {dest.relative_to(ROOT) if dest.is_relative_to(ROOT) else dest}")
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            broken.append(f"{target}: no heading with anchor #{anchor} in {dest.name}")
    assert not broken, "\n".join(broken)


def tracked_text_files() -> list[Path]:
    try:
        names = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout: the tracked files are unknown")
    files = [ROOT / n for n in names.splitlines()]
    return [f for f in files if f.suffix in TEXT_SUFFIXES and f.is_file()]


def test_no_tracked_text_tells_the_story_of_its_making():
    found = []
    for path in tracked_text_files():
        try:
            text = path.read_text()
        except UnicodeDecodeError:
            continue
        for number, line in enumerate(text.splitlines(), 1):
            if HISTORY.search(line):
                found.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()[:100]}")
    assert not found, "history wording (describe the product instead):\n" + "\n".join(found[:40])


def test_the_history_check_catches_what_it_looks_for():
    # the examples are assembled so that this file does not hold the wording it forbids
    for text in ("as measured in sess" + "ion 12", "Earlier sess" + "ions found", "targets (iss" + "ue 3)",
                 "see ../sha" + "red/x.md", "on the earlier mach" + "ine", "sha" + "red/reference/paper.md"):
        assert HISTORY.search(text), text
    for text in ("a session of training", "the issue of timing", "docs/results.md"):
        assert not HISTORY.search(text), text

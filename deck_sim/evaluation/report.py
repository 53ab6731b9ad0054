"""The evaluation's reports: per scene-and-agent summaries with 95 % intervals, the paper's Tables 1-3 beside
ours as Markdown, and the files ``write_report`` writes."""

from __future__ import annotations

import csv
import json
import math
import os
import platform
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from deck_sim.agents import AGENTS
from deck_sim.metrics import OUTCOMES, mean_interval, rate_interval

if TYPE_CHECKING:
    from deck_sim.evaluation.harness import EvalResults

PAPER = {
    # Success rate ("accuracy", mean of 100 sampled episodes) and mean path length / total turning angle
    # (degrees, Unity units) of the paper's Tables 1-3; the paper reports deck scenes only.
    "success": {
        "deck1": {"dqn": 0.90, "a2c": 0.67, "ddpg": 0.92, "mddpg": 0.98},
        "deck2": {"dqn": 0.84, "a2c": 0.64, "ddpg": 0.82, "mddpg": 0.91},
    },
    "path_length": {
        "deck1": {"dqn": 438.22, "a2c": 352.60, "ddpg": 328.97, "mddpg": 328.95},
        "deck2": {"dqn": 465.45, "a2c": 324.16, "ddpg": 320.61, "mddpg": 315.68},
    },
    "turning_deg": {
        "deck1": {"dqn": 586.73, "a2c": 142.03, "ddpg": 139.96, "mddpg": 139.80},
        "deck2": {"dqn": 522.62, "a2c": 158.00, "ddpg": 134.28, "mddpg": 128.41},
    },
}


def summarize_agent(rows: Sequence[dict[str, Any]], scene: str, agent: str) -> dict[str, Any]:
    """Rates (with Wilson 95 % intervals) and means (with normal 95 % intervals) of one agent on one scene.

    Path length, its ratio to the shortest static path, turning angle and time to goal are over successful
    episodes (as the paper's tables); reward, clearance and near misses over all; ADE/FDE over the episodes the
    predictor ran in, weighted by the (step, mover) samples scored.
    """
    mine = [r for r in rows if r["scene"] == scene and r["agent"] == agent]
    n = len(mine)
    out: dict[str, Any] = {"scene": scene, "agent": agent, "episodes": n}
    if not n:
        return out
    out["predictor"] = mine[0]["predictor"]
    for o in OUTCOMES:
        k = sum(r["outcome"] == o for r in mine)
        lo, hi = rate_interval(k, n)
        out[f"{o}_rate"], out[f"{o}_ci"] = k / n, [lo, hi]
    ok = [r for r in mine if r["outcome"] == "goal"]
    ratios = [r["path_length"] / r["shortest_path"] for r in ok if r["shortest_path"] > 0]
    for name, values in (
        ("reward", [r["reward"] for r in mine]),
        ("path_length", [r["path_length"] for r in ok]),
        ("shortest_ratio", ratios),
        ("turning_deg", [r["turning_angle_deg"] for r in ok]),
        ("time_to_goal", [r["sim_time"] for r in ok]),
        ("min_clearance", [r["min_clearance"] for r in mine]),
        ("near_misses", [r["near_misses"] for r in mine]),
    ):
        m, lo, hi = mean_interval(values)
        out[name], out[f"{name}_ci"] = m, [lo, hi]
    out["worst_clearance"] = float(min(r["min_clearance"] for r in mine))
    out["near_miss_m"] = float(mine[0]["near_miss_m"])
    scored = [r for r in mine if r["prediction_samples"] > 0]
    weights = np.array([r["prediction_samples"] for r in scored], dtype=np.float64)
    for name in ("ade", "fde"):
        out[name] = float(np.average([r[name] for r in scored], weights=weights)) if scored else float("nan")
    out["collision_partners"] = _count(r["collision_partner"] for r in mine if r["outcome"] == "collision")
    if "aircraft" in mine[0]:
        out.update(_team_summary(mine))
    return out


def _team_summary(mine: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The episode-level figures of a multi-aircraft scene (rows: one per aircraft): episodes and aircraft, the
    share of episodes in which every aircraft arrived, the mean makespan of those, aircraft-aircraft collisions per
    episode (each with its 95 % interval)."""
    episodes = {r["episode"]: r for r in mine}  # (the team figures repeat on every aircraft's row)
    n = len(episodes)
    full = [r for r in episodes.values() if r["all_reached"]]
    lo, hi = rate_interval(len(full), n)
    out: dict[str, Any] = {"episodes": n, "aircraft": len(mine), "all_reached_rate": len(full) / n,
                           "all_reached_ci": [lo, hi]}
    for name, values in (
        ("makespan", [r["makespan"] for r in full]),
        ("aircraft_collisions", [r["aircraft_collisions"] for r in episodes.values()]),
    ):
        m, lo, hi = mean_interval(values)
        out[name], out[f"{name}_ci"] = m, [lo, hi]
    return out


def _count(items: Iterable[str | None]) -> dict[str, int]:
    counts: dict[str, int] = {}
    for it in items:
        kind = str(it).rstrip("0123456789_/").split("/")[-1] or str(it)
        counts[kind] = counts.get(kind, 0) + 1
    return dict(sorted(counts.items(), key=lambda kv: -kv[1]))


def _pct(s: dict, key: str) -> str:
    lo, hi = s[f"{key}_ci"]
    return f"{100 * s[f'{key}_rate']:.1f} ({100 * lo:.0f}-{100 * hi:.0f})"


def _num(s: dict, key: str, spec: str = ".1f") -> str:
    v = s.get(key, float("nan"))
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    lo, hi = s[f"{key}_ci"]
    half = (hi - lo) / 2
    return f"{v:{spec}} ± {half:{spec}}"


def _paper(table: str, scene: str, agent: str, spec: str) -> str:
    # an agent learnt by the paper's protocol under another name (``mddpg-reward``) stands beside its algorithm's
    info = AGENTS.get(agent)
    v = PAPER[table].get(scene, {}).get(info.algo if info is not None and info.algo else agent)
    if v is None:
        return "-"
    return f"{100 * v:.0f}" if table == "success" else f"{v:{spec}}"


def _find(res: EvalResults, scene: str, agent: str) -> dict[str, Any] | None:
    try:
        return res.summary(scene, agent)
    except KeyError:
        return None


def _evaluated(res: EvalResults, scenes: list[str], agents: list[str]) -> Iterator[tuple[str, str, dict[str, Any]]]:
    """(scene, agent, summary) of every pair that was evaluated, scene-major."""
    for s in scenes:
        for a in agents:
            x = _find(res, s, a)
            if x is not None:
                yield s, a, x


def markdown_tables(res: EvalResults) -> str:
    """The paper's tables (success; path length and turning angle) with ours beside them, then every metric.

    A scene and agent pair that was not evaluated reads ``n/a``.
    """
    scenes = list(dict.fromkeys(s["scene"] for s in res.summaries))
    agents = list(dict.fromkeys(s["agent"] for s in res.summaries))
    n = res.config.episodes
    lines = [
        f"Each cell: {n} held-out episodes per scene and agent (seeds {res.config.seed}-{res.config.seed + n - 1}); "
        "rates in % with Wilson 95 % intervals, means ± the half-width of their Student-t 95 % interval. "
        "Path length, its ratio and turning angle are over successful episodes, as in the paper. "
        "`apf`, `astar`, `mpc` and `scripted` plan on the task's privileged view (every obstacle's exact footprint "
        "and the movers' forecast), not on the observation the learned agents get; `scripted-observed` plans on "
        "the observation alone (the observed footprints and the MPC forecast).",
        "",
        "**Success rate, % (paper Table 1)**: the paper's figure is the mean of 100 success rates sampled from its "
        "training curves in Unity; ours is the shipped policy on held-out episodes.",
        "",
        "| agent | " + " | ".join(f"{s} ours | {s} paper" for s in scenes) + " |",
        "|---|" + "---:|---:|" * len(scenes),
    ]
    for a in agents:
        cells = []
        for s in scenes:
            x = _find(res, s, a)
            cells += [_pct(x, "goal") if x else "n/a", _paper("success", s, a, ".0f")]
        lines.append(f"| {a} | " + " | ".join(cells) + " |")
    lines += [
        "",
        "**Path length and turning angle (paper Tables 2-3)**: ours in metres and as a ratio to the shortest path "
        "around the static obstacles of a disc as wide as the agent's narrowest half-extent, ending on the goal "
        "disc (a lower bound of any collision-free path; the paper's Unity units do not convert); turning angle "
        "in degrees per episode.",
        "",
        "| agent | scene | length m | length / shortest | turning deg | paper length (Unity) | paper turning deg |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for s, a, x in _evaluated(res, scenes, agents):
        lines.append(
            f"| {a} | {s} | {_num(x, 'path_length')} | {_num(x, 'shortest_ratio', '.3f')} | "
            f"{_num(x, 'turning_deg')} | {_paper('path_length', s, a, '.2f')} | "
            f"{_paper('turning_deg', s, a, '.2f')} |"
        )
    lines += prediction_differences(res, scenes)
    lines += team_table(res, scenes, agents)
    lines += [
        "",
        "**Reward and safety** (the paper gives reward only as curves: about 150 at the plateau for DQN, DDPG and "
        "MDDPG, about 100 for A2C, on its own reward constants)",
        "",
        "Near misses: passes closer than the threshold (clearance between the agent's disc and an obstacle's "
        "footprint); worst clearance: the smallest over all episodes (negative: the discs overlapped).",
        "",
        "| agent | scene | predictor | collision % | timeout % | off surface % | diverged % | mean reward "
        "| time to goal s | near misses / ep (threshold) | worst clearance m | ADE m | FDE m |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for s, a, x in _evaluated(res, scenes, agents):
        ade = "-" if math.isnan(x["ade"]) else f"{x['ade']:.2f}"
        fde = "-" if math.isnan(x["fde"]) else f"{x['fde']:.2f}"
        lines.append(
            f"| {a} | {s} | {x['predictor']} | {_pct(x, 'collision')} | {_pct(x, 'timeout')} | "
            f"{_pct(x, 'off_surface')} | {_pct(x, 'diverged')} | {_num(x, 'reward')} | "
            f"{_num(x, 'time_to_goal')} | {_num(x, 'near_misses', '.2f')} ({x['near_miss_m']:g} m) | "
            f"{x['worst_clearance']:.2f} | {ade} | {fde} |"
        )
    return "\n".join(lines) + "\n"


def team_table(res: EvalResults, scenes: list[str], agents: list[str]) -> list[str]:
    """The multi-aircraft scenes' table: aircraft that arrived, episodes in which every one did, makespan and
    aircraft-aircraft collisions (no lines when no such scene was evaluated)."""
    rows = [(s, a, x) for s, a, x in _evaluated(res, scenes, agents) if "all_reached_rate" in x]
    if not rows:
        return []
    lines = [
        "",
        "**Several aircraft**: on a multi-aircraft scene the tables above count aircraft (every aircraft of every "
        "episode, its path up to where it was done); here, per episode: every aircraft arrived, the time until the "
        "last one did (those episodes), collisions between two aircraft.",
        "",
        "| agent | scene | episodes | aircraft | aircraft reached % | all arrived % | makespan s | "
        "aircraft-aircraft collisions / episode |",
        "|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    for s, a, x in rows:
        lines.append(
            f"| {a} | {s} | {x['episodes']} | {x['aircraft']} | {_pct(x, 'goal')} | {_pct(x, 'all_reached')} | "
            f"{_num(x, 'makespan')} | {_num(x, 'aircraft_collisions', '.2f')} |"
        )
    return lines


def prediction_differences(res: EvalResults, scenes: list[str]) -> list[str]:
    """Lines stating, per scene where both were evaluated, whether MDDPG's path is longer or shorter than DDPG's
    and whether it turns more or less (or as much, within the printed 0.1 m or deg), ours and the paper's
    (Tables 2-3), with whether our 95 % intervals overlap."""
    lines: list[str] = []
    for s in scenes:
        m, d = _find(res, s, "mddpg"), _find(res, s, "ddpg")
        if m is None or d is None:
            continue
        for key, unit, more, less in (
            ("path_length", "m", "longer", "shorter"),
            ("turning_deg", "deg", "more", "less"),
        ):
            ours = m.get(key, float("nan")) - d.get(key, float("nan"))
            if math.isnan(ours):
                continue
            (m_lo, m_hi), (d_lo, d_hi) = m[f"{key}_ci"], d[f"{key}_ci"]
            overlap = "the intervals overlap" if m_lo <= d_hi and d_lo <= m_hi else "the intervals are apart"
            if f"{abs(ours):.1f}" == "0.0":  # (equal at the printed precision: "0.0 m shorter" would say nothing)
                same = "turns as much as DDPG" if key == "turning_deg" else "drives a path as long as DDPG's"
                text = f"- {s}: MDDPG {same} (within 0.05 {unit}; {overlap})"
            else:
                verb = "turns" if key == "turning_deg" else "drives a path"
                text = f"- {s}: MDDPG {verb} {abs(ours):.1f} {unit} {more if ours > 0 else less} than DDPG ({overlap})"
            paper = PAPER[key].get(s, {})
            if "mddpg" in paper and "ddpg" in paper:
                theirs = paper["mddpg"] - paper["ddpg"]
                text += f"; the paper's: {abs(theirs):.2f} {'Unity units' if unit == 'm' else unit} "
                text += f"{more if theirs > 0 else less}"
            lines.append(text + ".")
    if lines:
        lines = ["", "**MDDPG against DDPG without prediction, the direction of each difference**:", "", *lines]
    return lines


def jsonable(x: Any) -> Any:
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [jsonable(v) for v in x]
    return x


def machine() -> str:
    """A one-line description of this machine (for reports)."""
    return f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"


def write_report(res: EvalResults, out: str | os.PathLike[str]) -> dict[str, Path]:
    """Write ``summary.json``, ``summary.csv``, ``episodes.csv`` and ``results.md`` to ``out``; returns the paths.

    Each file is written to a temporary name and renamed, so a failure leaves no half-written report.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = {k: out / k for k in ("summary.json", "summary.csv", "episodes.csv", "results.md")}
    meta = {
        "config": asdict(res.config),
        "machine": machine(),
        "wall_s": res.wall_s,
        "evaluated": [[s["scene"], s["agent"]] for s in res.summaries],  # a merged config may list more pairs
        "summaries": res.summaries,
        "episodes": res.episodes,
    }
    _atomic_text(paths["summary.json"], json.dumps(jsonable(meta), indent=1))
    _atomic_csv(paths["episodes.csv"], res.episodes)
    flat = []
    for s in res.summaries:
        row = {}
        for k, v in s.items():
            if isinstance(v, list):
                row[f"{k}_low"], row[f"{k}_high"] = v
            elif isinstance(v, dict):
                row[k] = json.dumps(v)
            else:
                row[k] = v
        flat.append(row)
    _atomic_csv(paths["summary.csv"], flat)
    _atomic_text(paths["results.md"], "# deck_sim evaluation\n\n" + markdown_tables(res))
    return paths


def _atomic_text(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def _atomic_csv(path: Path, rows: Sequence[dict]) -> None:
    tmp = path.with_name(path.name + ".tmp")
    fields: list[str] = []
    for r in rows:
        fields += [k for k in r if k not in fields]
    with open(tmp, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields)
        w.writeheader()
        w.writerows(rows)
    os.replace(tmp, path)



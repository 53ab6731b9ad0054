"""Does a trained MDDPG run's critic read the movers' motion in its forecast, and does its actor follow it?

``forecast_use.py`` plays an actor with the motion taken out of its forecast and finds the reward-alone actors'
success unchanged: they do not use it. This script asks where that is lost, on the states the run itself visited
(its replay buffer, ``training.checkpoints``: the networks and the buffer as the run last saved them). For each of
``--samples`` stored states (seeded, demonstrations left out) it builds the *stationary* view of the same state:
every mover's forecast replaced by where the mover is now (``predicted`` repeats ``dynamic_obstacles``, or is zero
in the mover frame; ``predicted_near`` repeats ``dynamic_near``), exactly what the ``stationary`` predictor puts
in the observation; nothing else changes. Then, with ``K`` random actions (``--actions``, uniform in the action
box, seeded) besides the actor's own, it prints per run:

- **critic**: the action the critic rates best among them with the forecast and with the stationary view, how far
  apart the two are (action units; the box is [-1, 1] per axis), and what choosing on the stationary view costs by
  the critic's own reckoning with the forecast: Q(s, a*) - Q(s, a*_stationary), in the critic's units
  (``reward_scale`` x the reward; a collision is ``reward_scale`` x the scene's ``reward.collision``). A best of
  many is never below another pick, so this cost is never negative;
- **actor**: how far its action moves with the stationary view, and what that costs by the same critic:
  Q(s, pi(s)) - Q(s, pi(s_stationary)), a mean difference of either sign;
- the spread of Q over the random actions (best minus median), the scale the costs compare with;
- with twin critics, the same shift and cost between the two heads' best actions on the same state (the cost by
  the Q the run's TD target takes, ``twin_min_weight``): how well the critic itself knows its best action;
- the critic's and the actor's shifts when the forecast is instead given ``--noise`` (1 m) of normal noise on every
  coordinate: how far an uninformative change of the same inputs moves either.

Each figure is a mean over all sampled states and over the *encounters*: states in which some mover that lies
within ``--near`` metres of the aircraft moves at least ``--moving`` metres over the forecast's horizon, the states
a forecast is for. A critic that moves its best action with the motion and an actor that does not means the
actor does not learn what its critic knows; a critic that ignores the motion too means the reward's value signal
does not reach it.

    python benchmarks/forecast_reads.py runs/switches/deck1-reward-mddpg-with-close-seed0 [RUN ...]
        [--samples 2000] [--actions 256] [--near 30] [--moving 1] [--noise 1]
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MUJOCO_GL", "disable")

import argparse  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402
from common import machine  # noqa: E402

from deck_sim.scenes import load_scene  # noqa: E402
from training.checkpoints import CheckpointError, load_run_agent  # noqa: E402
from training.envs import ObservationLayout, scene_layout  # noqa: E402


def stationary_view(flat: np.ndarray, layout: ObservationLayout, mover_frame: bool = False) -> np.ndarray:
    """Flat observations (n, layout.dim) with every mover's forecast replaced by where it is now (the
    ``stationary`` predictor's observation of the same state): ``predicted`` repeats ``dynamic_obstacles`` (zero
    where ``mover_frame``: the forecast as each mover's own displacement), ``predicted_near`` repeats
    ``dynamic_near``. Refuses a layout with ``predicted_approach``, which depends on the aircraft's motion as well."""
    if "predicted" not in layout.shapes:
        raise ValueError("the observation has no forecast (`predicted`): a DDPG run, not MDDPG")
    if "predicted_approach" in layout.shapes:
        raise ValueError("`predicted_approach` is observed: its stationary value is not rebuilt here")
    if "predicted_near" in layout.shapes and "dynamic_near" not in layout.shapes:
        raise ValueError("`predicted_near` is observed without `dynamic_near`: its stationary value is not rebuilt "
                         "here")
    sl, out = layout.slices(), flat.copy()
    n, horizon, _ = layout.shapes["predicted"]
    rows = len(flat)
    now = np.zeros((rows, n, 1, 2), flat.dtype) if mover_frame else flat[:, sl["dynamic_obstacles"]].reshape(
        rows, n, 1, 2)
    out[:, sl["predicted"]] = np.broadcast_to(now, (rows, n, horizon, 2)).reshape(rows, -1)
    if "predicted_near" in layout.shapes:
        near = flat[:, sl["dynamic_near"]].reshape(rows, n, 1, 2)
        out[:, sl["predicted_near"]] = np.broadcast_to(near, (rows, n, horizon, 2)).reshape(rows, -1)
    return out


def encounters(flat: np.ndarray, layout: ObservationLayout, near: float, moving: float,
               mover_frame: bool = False) -> np.ndarray:
    """(n,) bool: some mover within ``near`` metres of the aircraft (its centre, now) moves at least ``moving``
    metres from now to the forecast's last step."""
    sl = layout.slices()
    n, horizon, _ = layout.shapes["predicted"]
    now = flat[:, sl["dynamic_obstacles"]].reshape(-1, n, 2)
    last = flat[:, sl["predicted"]].reshape(-1, n, horizon, 2)[:, :, -1]
    shift = last if mover_frame else last - now
    return ((np.linalg.norm(now, axis=-1) <= near) & (np.linalg.norm(shift, axis=-1) >= moving)).any(axis=1)


def jittered_view(flat: np.ndarray, layout: ObservationLayout, noise: float, rng: np.random.Generator
                  ) -> np.ndarray:
    """Flat observations (n, layout.dim) with independent normal noise of ``noise`` metres on every coordinate of
    the forecast's keys (``predicted``, ``predicted_near``): a change of the forecast that carries no information,
    the reference for the stationary view's shifts."""
    sl, out = layout.slices(), flat.copy()
    for key in ("predicted", "predicted_near"):
        if key in layout.shapes:
            out[:, sl[key]] += rng.normal(0.0, noise, out[:, sl[key]].shape).astype(out.dtype)
    return out


def forecast_reads(run: Path, samples: int, actions: int, near: float, moving: float, noise: float = 1.0,
                   seed: int = 0) -> dict[str, dict[str, float]]:
    """The figures of the module docstring for one run folder: {"all": ..., "encounters": ...}, each with
    ``states``, ``critic_shift``, ``critic_cost``, ``actor_shift``, ``actor_cost``, ``spread``, ``heads_shift``,
    ``heads_cost`` (NaN for a single critic), ``noise_critic_shift`` and ``noise_actor_shift``."""
    state, cfg, agent = load_run_agent(run)
    layout = scene_layout(cfg.scene, cfg.predictor, cfg.scene_overrides)
    buf = state["buffer"]
    obs_all = buf["obs"][int(buf["n_demo"]):].numpy()
    if len(obs_all) == 0:
        raise CheckpointError(f"{run}: its replay buffer holds no state of its own (demonstrations only)")
    if obs_all.shape[1] != layout.dim:
        raise CheckpointError(f"{run}: its buffer's observations have {obs_all.shape[1]} values, the scene's "
                              f"layout {layout.dim}: a run of another code version or scene")
    mover_frame = load_scene(cfg.scene, **cfg.scene_overrides).episode.predicted_frame == "mover"
    rng = np.random.default_rng(seed)
    obs = obs_all[rng.choice(len(obs_all), size=min(samples, len(obs_all)), replace=False)]
    still = stationary_view(obs, layout, mover_frame)
    noisy = jittered_view(obs, layout, noise, rng)
    act_dim = int(buf["action"].shape[1])
    grid = torch.from_numpy(rng.uniform(-1.0, 1.0, (actions, act_dim)).astype(np.float32))

    def q_of(x: torch.Tensor, a: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(rows, k) Q of each row's observation ``x`` (normalised) with each of its k actions ``a`` (rows, k, d),
        and (heads, rows, k) each head's."""
        rows, k = a.shape[:2]
        xs = x[:, None].expand(rows, k, x.shape[1]).reshape(rows * k, -1)
        heads = torch.stack(agent.critic(xs, a.reshape(rows * k, -1)))
        return agent.combine_heads(heads).reshape(rows, k), heads.reshape(len(heads), rows, k)

    parts = []
    with torch.no_grad():
        for i in range(0, len(obs), 64):
            x, xs = agent.norm(torch.from_numpy(obs[i:i + 64])), agent.norm(torch.from_numpy(still[i:i + 64]))
            xn = agent.norm(torch.from_numpy(noisy[i:i + 64]))
            pi, pi_s, pi_n = agent.actor(x), agent.actor(xs), agent.actor(xn)
            cand = torch.cat([grid[None].expand(len(x), -1, -1), pi[:, None], pi_s[:, None]], dim=1)
            (q, heads), (q_s, _), (q_n, _) = q_of(x, cand), q_of(xs, cand), q_of(xn, cand)
            best, best_s, best_n = q[:, :actions].argmax(1), q_s[:, :actions].argmax(1), q_n[:, :actions].argmax(1)
            rows = torch.arange(len(x))
            h0, h1 = heads[0, :, :actions].argmax(1), heads[-1, :, :actions].argmax(1)
            parts.append(np.stack([
                (grid[best] - grid[best_s]).norm(dim=1).numpy(),
                (q[rows, best] - q[rows, best_s]).numpy(),
                (pi - pi_s).norm(dim=1).numpy(),
                (q[:, actions] - q[:, actions + 1]).numpy(),
                (q[rows, best] - q[:, :actions].median(1).values).numpy(),
                (grid[h0] - grid[h1]).norm(dim=1).numpy(),
                (q[rows, h0] - q[rows, h1]).abs().numpy(),
                (grid[best] - grid[best_n]).norm(dim=1).numpy(),
                (pi - pi_n).norm(dim=1).numpy(),
            ], axis=1))
    figures = np.concatenate(parts).astype(np.float64)
    names = ("critic_shift", "critic_cost", "actor_shift", "actor_cost", "spread", "heads_shift", "heads_cost",
             "noise_critic_shift", "noise_actor_shift")
    out = {}
    for label, mask in (("all", np.ones(len(obs), bool)),
                        ("encounters", encounters(obs, layout, near, moving, mover_frame))):
        sub = figures[mask]
        out[label] = {"states": int(mask.sum()),
                      **{k: float(sub[:, j].mean()) if len(sub) else float("nan") for j, k in enumerate(names)}}
    out["all"]["steps"] = int(state["step"])
    if len(agent.critic.heads) < 2:  # (one critic: no second opinion to compare with)
        for f in out.values():
            f["heads_shift"] = f["heads_cost"] = float("nan")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=Path, help="MDDPG run folders holding checkpoint.pt")
    parser.add_argument("--samples", type=int, default=2000, help="stored states per run (seeded)")
    parser.add_argument("--actions", type=int, default=256, help="random actions the critic rates per state")
    parser.add_argument("--near", type=float, default=30.0, help="an encounter's mover lies within this, metres")
    parser.add_argument("--moving", type=float, default=1.0,
                        help="an encounter's mover moves at least this over the horizon, metres")
    parser.add_argument("--noise", type=float, default=1.0,
                        help="standard deviation of the reference's noise on the forecast, metres")
    args = parser.parse_args()
    if args.samples < 1 or args.actions < 2 or not args.noise >= 0:
        parser.error("--samples: at least 1; --actions: at least 2; --noise: not negative")
    print(machine(torch=torch.__version__))
    print("shift: distance between the actions chosen with the forecast and with the stationary view (action units);"
          " cost: what the stationary choice loses by the critic's Q with the forecast (critic units); spread: best "
          "minus median Q over the random actions")
    print(f"noise: the shifts with {args.noise:g} m of normal noise on every forecast coordinate in place of the "
          "stationary view (a change that carries no information)")
    print("| run | steps | states | count | critic shift | critic cost | actor shift | actor cost | spread | "
          "heads shift | heads cost | noise critic shift | noise actor shift |")
    print("|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    failed = False
    for run in args.runs:
        try:
            r = forecast_reads(run, args.samples, args.actions, args.near, args.moving, args.noise)
        except (CheckpointError, ValueError) as err:
            print(f"{run}: {err}", file=sys.stderr)
            failed = True
            continue
        for label in ("all", "encounters"):
            f = r[label]
            print(f"| {run.name} | {r['all']['steps']} | {label} | {f['states']} | {f['critic_shift']:.3f} | "
                  f"{f['critic_cost']:.3f} | {f['actor_shift']:.3f} | {f['actor_cost']:+.3f} | {f['spread']:.3f} | "
                  f"{f['heads_shift']:.3f} | {f['heads_cost']:.3f} | {f['noise_critic_shift']:.3f} | "
                  f"{f['noise_actor_shift']:.3f} |".replace("nan", "-"),
                  flush=True)
    if failed:
        raise SystemExit(1)


if __name__ == "__main__":
    main()

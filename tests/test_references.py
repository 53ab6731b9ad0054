"""The classical references (APF, A* with replanning, MPC) on hand-made views and on real scenes."""

import numpy as np
import pytest

import deck_sim
from deck_sim.control.planners import APFPlanner, AStarPlanner, MPCPlanner
from deck_sim.geometry import Footprints
from deck_sim.policies import ScriptedPolicy
from deck_sim.rollout import run_episode
from deck_sim.types import PlannerView


def view(statics=None, movers=None, future=None, agent=(0.0, 0.0), target=(60.0, 0.0)) -> PlannerView:
    movers = movers or Footprints.empty()
    if future is None:
        future = np.repeat(movers.centers[:, None], 10, axis=1)
    return PlannerView(
        agent_xy=np.array(agent, dtype=float),
        agent_yaw=0.0,
        agent_speed=0.0,
        agent_radius=2.0,
        target_xy=np.array(target, dtype=float),
        goal_radius=2.0,
        statics=statics or Footprints.empty(),
        movers=movers,
        mover_future=future,
        bounds=np.array([[-100.0, -50.0], [100.0, 50.0]]),
        reach=3.0,
        period=0.5,
    )


def box(x: float, y: float, hx: float = 2.0, hy: float = 2.0) -> Footprints:
    return Footprints(np.array([[x, y]]), np.array([[hx, hy]]), np.zeros(1), np.zeros(1))


PLANNERS = [APFPlanner, AStarPlanner, MPCPlanner]


@pytest.mark.parametrize("planner", PLANNERS, ids=lambda p: p.__name__)
def test_in_the_open_every_reference_heads_straight_for_the_target(planner):
    p = planner()
    p.reset()
    a = p.act(view())
    assert a.shape == (2,) and np.all(np.abs(a) <= 1.0)
    assert a[0] > 0.8 and abs(a[1]) < 0.05  # the MPC eases in from rest (its smoothness term)


@pytest.mark.parametrize("planner", PLANNERS, ids=lambda p: p.__name__)
def test_every_reference_slows_so_as_not_to_overshoot_the_goal(planner):
    a = planner().act(view(target=(2.0, 0.0)))
    assert 0.0 < np.linalg.norm(a) * 3.0 <= 2.0 - 0.5 * 2.0 + 1e-6


def test_apf_is_pushed_away_from_an_obstacle_beside_it():
    a = APFPlanner().act(view(statics=box(6.0, 4.5, 2.0, 0.5)))  # obstacle ahead and to the left
    assert a[1] < -0.05  # it veers right


def test_astar_goes_round_a_mover_sweeping_across_its_path():
    movers = Footprints(np.array([[20.0, 10.0]]), np.array([[2.0, 1.0]]), np.array([-np.pi / 2]), np.zeros(1))
    future = np.stack([np.array([20.0, 10.0 - 2.0 * k]) for k in range(1, 11)])[None]  # drives down through y=0
    planner = AStarPlanner()
    path = planner.path(view(movers=movers, future=future))
    assert path is not None and len(path) > 2  # not the straight line
    sweep = planner.sweeps(view(movers=movers, future=future))
    assert sweep.distance(path[1:-1]).min() > 0  # its corners lie outside the sweep


def test_astar_stands_still_when_boxed_in():
    ring = Footprints.concatenate([box(0, 12, 14, 2), box(0, -12, 14, 2), box(12, 0, 2, 14), box(-12, 0, 2, 14)])
    assert np.all(AStarPlanner().act(view(statics=ring)) == 0.0)


def test_mpc_leaves_its_reference_to_pass_a_mover_standing_on_it():
    movers = box(9.0, 0.3, 2.0, 1.0)
    free = MPCPlanner().act(view())
    blocked = MPCPlanner()
    a = blocked.act(view(movers=movers))
    assert blocked.last_status in ("Solve_Succeeded", "Solved_To_Acceptable_Level")
    assert abs(a[1]) > abs(free[1]) + 0.1  # it swerves (the mover is slightly left: it swerves right)
    assert a[1] < 0


@pytest.mark.slow
@pytest.mark.parametrize("name,planner", [("apf", APFPlanner), ("astar", AStarPlanner), ("mpc", MPCPlanner)])
def test_every_reference_reaches_deck1_targets_among_movers(name, planner):
    env = deck_sim.load("deck1", seed=3, episode__predictor="mpc")
    policy = ScriptedPolicy(env, planner())
    outcomes = []
    for k in range(2):
        env.random_state.seed(100_000 + k)
        outcomes.append(run_episode(env, policy, k).outcome)
    assert outcomes.count("goal") >= 1, outcomes


def test_cli_runs_a_classical_reference_with_the_mpc_predictor(tmp_path, capsys):
    from deck_sim.cli import main

    rc = main(["run", "--scene", "deck1", "--policy", "apf", "--episodes", "1", "--seed", "3", "--no-record",
               "--out", str(tmp_path), "--quiet"])  # fmt: skip
    assert rc == 0
    assert "policy apf, predictor mpc" in capsys.readouterr().out

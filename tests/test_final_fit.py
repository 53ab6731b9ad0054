"""The end of a run: the final cloning fit (``polish_epochs``, ``polish_hidden``) and the DAgger round
(``dagger_steps``), each added to a finished run by resuming it, and the actor file that a run ships."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import short_config as _short
from training_runs import actor_arrays, csv_rows

from training.config import ConfigError, make_config
from training.loop import CheckpointError, Trainer, load_checkpoint, shipped_actor


@pytest.fixture(scope="module")
def plain_run(tmp_path_factory: pytest.TempPathFactory) -> Trainer:
    """A finished short run without the final fit: a test copies its folder before resuming it."""
    plain = Trainer(_short(), tmp_path_factory.mktemp("plain") / "run", progress=False)
    plain.train()
    return plain


def _copy_of(run_dir: Path, to: Path) -> Path:
    shutil.copytree(run_dir, to)
    return to


@pytest.mark.slow
def test_polishing_fits_the_buffer_and_a_finished_run_can_be_polished_later(tmp_path, plain_run):
    """The final cloning fit lowers the cloning loss over the buffer, adds a marked evaluation at the last step,
    and gives the same actor whether it was asked for from the start or added by resuming the finished run."""
    polished = Trainer(_short(polish_epochs=30), tmp_path / "polished", progress=False)
    polished.train()
    plain = plain_run
    _copy_of(plain.run_dir, tmp_path / "plain")
    rows = np.flatnonzero(plain.buffer.labelled[: plain.buffer.size] > 0)
    assert len(rows) == plain.buffer.size  # demonstrations and relabelled transitions all carry the planner's label

    def cloning_loss(trainer: Trainer) -> float:
        with torch.no_grad():
            obs = trainer.agent.norm(torch.as_tensor(trainer.buffer.obs[rows]))
            err = trainer.agent.actor(obs) - torch.as_tensor(trainer.buffer.expert_action[rows])
        return float((err**2).sum(-1).mean())

    assert cloning_loss(polished) < 0.5 * cloning_loss(plain)
    evals = csv_rows(tmp_path / "polished" / "eval.csv")
    assert [(r["step"], r["polished"]) for r in evals] == [("120", "0"), ("120", "1")]
    meta = json.loads(str(np.load(tmp_path / "polished" / "actor.npz", allow_pickle=False)["meta"]))
    assert meta["polished"] is True
    # what is shipped: the fitted final actor, else the best evaluation's
    assert shipped_actor(tmp_path / "polished") == tmp_path / "polished" / "actor.npz"
    assert shipped_actor(tmp_path / "plain") == tmp_path / "plain" / "actor_best.npz"
    later = Trainer(_short(polish_epochs=30), tmp_path / "plain", resume=True, progress=False)
    later.train()
    assert shipped_actor(tmp_path / "plain") == tmp_path / "plain" / "actor.npz"
    assert [r["polished"] for r in csv_rows(tmp_path / "plain" / "eval.csv")] == ["0", "1"]  # no second online row
    assert csv_rows(tmp_path / "plain" / "eval.csv") == evals
    for name in ("actor.npz", "actor_best.npz"):
        with np.load(tmp_path / "polished" / name) as a, np.load(tmp_path / "plain" / name) as b:
            for k in a.files:
                if k != "meta":
                    np.testing.assert_array_equal(a[k], b[k], err_msg=f"{name} {k}")
    again = Trainer(_short(polish_epochs=30), tmp_path / "plain", resume=True, progress=False)
    again.train()  # polished once: resuming again changes nothing
    assert len(csv_rows(tmp_path / "plain" / "eval.csv")) == 2
    # a polished run is finished: neither extended nor polished again with other settings
    with pytest.raises(CheckpointError, match="cannot be extended"):
        Trainer(_short(polish_epochs=30, total_steps=160), tmp_path / "plain", resume=True, progress=False).train()
    with pytest.raises(CheckpointError, match="polished with polish_epochs = 30"):
        Trainer(_short(polish_epochs=5), tmp_path / "plain", resume=True, progress=False).train()
    for bad in (-1, 2.0):
        with pytest.raises(ConfigError, match="polish_epochs"):
            make_config(polish_epochs=bad)


@pytest.mark.slow
def test_a_dagger_round_labels_the_fitted_actors_own_states_and_fits_again(tmp_path):
    """``dagger_steps``: after the final fit the fitted actor drives more steps, greedy and without updates (the
    critic and the normaliser stay as they are), every state labelled by the planner, then the fit is made again
    on all of them and evaluated; asking for the round from the start or adding it to a fitted run by resuming
    gives the same actor; a round is neither repeated nor undone."""
    from training.config import arm_config

    fitted = Trainer(_short(polish_epochs=5), tmp_path / "fitted", progress=False)
    fitted.train()
    size, critic = fitted.buffer.size, [p.detach().clone() for p in fitted.agent.critic.parameters()]
    norm = fitted.agent.norm.state_dict()
    later = Trainer(_short(polish_epochs=5, dagger_steps=40), tmp_path / "fitted", resume=True, progress=False)
    later.train()
    assert later.step == 160 and later.buffer.size == size + 40 and later.dagger_done == 40
    rows = np.flatnonzero(later.buffer.labelled[: later.buffer.size] > 0)
    assert len(rows) == later.buffer.size  # the round's states carry the planner's label too
    # the round acted with the fitted actor's greedy action: stored actions are that actor's on the stored states
    greedy = fitted.agent.act(later.buffer.obs[size : size + 40])
    np.testing.assert_allclose(later.buffer.action[size : size + 40], np.clip(greedy, -1, 1), rtol=0, atol=1e-6)
    for a, b in zip(critic, later.agent.critic.parameters(), strict=True):  # no updates
        torch.testing.assert_close(a, b, rtol=0, atol=0)
    for k, v in norm.items():
        torch.testing.assert_close(v, later.agent.norm.state_dict()[k], rtol=0, atol=0)
    evals = csv_rows(tmp_path / "fitted" / "eval.csv")
    assert [(r["step"], r["polished"]) for r in evals] == [("120", "0"), ("120", "1"), ("160", "1")]
    meta = json.loads(str(np.load(tmp_path / "fitted" / "actor.npz", allow_pickle=False)["meta"]))
    assert meta["polished"] is True and meta["trained_steps"] == 160 and meta["config"]["dagger_steps"] == 40
    # from the start: the same actor and evaluations
    whole = Trainer(_short(polish_epochs=5, dagger_steps=40), tmp_path / "whole", progress=False)
    whole.train()
    assert csv_rows(tmp_path / "whole" / "eval.csv") == evals
    for k, v in actor_arrays(tmp_path / "whole").items():
        np.testing.assert_array_equal(v, actor_arrays(tmp_path / "fitted")[k], err_msg=k)
    # stopped halfway through the round (it starts at step 120): no actor, the fitted checkpoint stays; resumed,
    # the round starts again from there and ends as the uninterrupted run
    stopped = Trainer(_short(polish_epochs=5, dagger_steps=40), tmp_path / "stopped", progress=False)
    tick = stopped._tick

    def tick_then_stop() -> None:
        tick()
        stopped._stop = stopped._stop or stopped.step >= 140

    stopped._tick = tick_then_stop
    stopped.train()
    assert not (tmp_path / "stopped" / "actor.npz").exists()
    saved = load_checkpoint(tmp_path / "stopped" / "checkpoint.pt")
    assert (saved["step"], saved["polished"], saved["dagger_done"]) == (120, True, 0)
    Trainer(_short(polish_epochs=5, dagger_steps=40), tmp_path / "stopped", resume=True, progress=False).train()
    assert csv_rows(tmp_path / "stopped" / "eval.csv") == evals
    for k, v in actor_arrays(tmp_path / "whole").items():
        np.testing.assert_array_equal(v, actor_arrays(tmp_path / "stopped")[k], err_msg=k)
    again = Trainer(_short(polish_epochs=5, dagger_steps=40), tmp_path / "whole", resume=True, progress=False)
    again.train()  # the round is done: resuming changes nothing
    assert again.step == 160 and len(csv_rows(tmp_path / "whole" / "eval.csv")) == 3
    with pytest.raises(CheckpointError, match="DAgger round of 40 steps"):
        Trainer(_short(polish_epochs=5), tmp_path / "whole", resume=True, progress=False).train()
    with pytest.raises(ConfigError, match="dagger_steps: needs the final fit"):
        make_config(dagger_steps=40)
    for bad in (-1, 2.5, True):
        with pytest.raises(ConfigError, match="dagger_steps"):
            make_config(polish_epochs=5, dagger_steps=bad)
    assert arm_config("tuned-mddpg-with-data+polish+dagger", "deck1", steps=10_000, seed=0).dagger_steps == 40_000


@pytest.mark.slow
def test_a_wider_final_fit_exports_an_actor_of_its_own_widths_and_resumes(tmp_path, plain_run):
    """``polish_hidden``: the final fit trains a fresh actor of other widths (the critic keeps ``hidden``); the
    exported file has those widths and acts; the polished run resumes with that actor; a finished run can be
    given the wider fit later, and not twice."""
    import deck_sim
    from deck_sim.policies import LearnedPolicy

    cfg = _short(polish_epochs=5, polish_hidden=(24, 16, 8))
    wide = Trainer(cfg, tmp_path / "wide", progress=False)
    wide.train()
    with np.load(tmp_path / "wide" / "actor.npz") as f:
        assert [f[f"w{i}"].shape for i in range(4)] == [(24, wide.obs_dim), (16, 24), (8, 16), (2, 8)]
        assert "w4" not in f.files
    policy = LearnedPolicy.load(tmp_path / "wide" / "actor.npz")
    env = deck_sim.load("deck1", seed=0, **policy.scene_overrides)
    action = policy.act(env.reset().observation)
    assert action.shape == (2,) and np.all(np.abs(action) <= 1.0)
    again = Trainer(cfg, tmp_path / "wide", resume=True, progress=False)
    again.train()  # restores the polished checkpoint into an actor of the fit's widths
    for a, b in zip(wide.agent.actor.parameters(), again.agent.actor.parameters(), strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=0)
    # a finished, unpolished run given the wider fit later: the same actor as asking for it from the start
    Trainer(cfg, _copy_of(plain_run.run_dir, tmp_path / "later"), resume=True, progress=False).train()
    with np.load(tmp_path / "wide" / "actor.npz") as a, np.load(tmp_path / "later" / "actor.npz") as b:
        for k in a.files:
            if k != "meta":
                np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    with pytest.raises(CheckpointError, match="polished with polish_hidden"):
        Trainer(_short(polish_epochs=5, polish_hidden=(32,)), tmp_path / "later", resume=True, progress=False).train()
    with pytest.raises(ConfigError, match="polish_hidden"):
        make_config(polish_hidden=(0, 8))

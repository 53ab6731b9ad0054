"""Ensembles of actors (``deck_sim.policies.EnsemblePolicy``): the mean of the members' actions, one weights-only
file that round-trips exactly, refusal of members that cannot act together, clear errors on broken files, and the
``deck-sim ensemble`` command."""

from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest
from conftest import run_steps

import deck_sim
from deck_sim.cli import main as cli
from deck_sim.policies import (
    ENSEMBLE_FORMAT,
    EnsemblePolicy,
    LearnedPolicy,
    PolicyFileError,
    load_actor,
    make_policy,
    shipped_policy_path,
    write_actor_file,
)
from deck_sim.rollout import run_episode


def _actor(algo: str = "ddpg", scene: str = "deck1") -> LearnedPolicy:
    """The single actor behind a shipped policy (an ensemble's first member if the shipped file is one)."""
    policy = load_actor(shipped_policy_path(algo, scene))
    return policy.members[0] if isinstance(policy, EnsemblePolicy) else policy


def _dies_half_way(file: object, *args: object, **kwargs: object) -> None:
    """A stand-in for ``np.savez_compressed`` whose write dies half-way: a part of a file, then an error."""
    with open(file, "wb") as f:
        f.write(b"PK\x03\x04 half a file")
    raise OSError("disk full")


def _perturbed(actor: LearnedPolicy, seed: int, scale: float = 0.5) -> LearnedPolicy:
    """Another actor on the same observation: the given one's weights plus seeded noise."""
    rng = np.random.default_rng(seed)
    arrays = dict(actor.arrays)
    for k in [k for k in arrays if k[0] in "wb" and k[1:].isdigit()]:
        arrays[k] = (arrays[k] + scale * rng.standard_normal(arrays[k].shape)).astype(arrays[k].dtype)
    return LearnedPolicy(arrays, {**actor.meta, "config": {**actor.meta["config"], "seed": seed}},
                         source=f"<perturbed {seed}>")


def _observations(policy, scene: str = "deck1", n: int = 12, seed: int = 5) -> list[dict[str, np.ndarray]]:
    """Observations of a seeded random walk in the environment ``policy`` needs (``conftest.run_steps``)."""
    return run_steps(deck_sim.load(scene, seed=seed, **policy.scene_overrides), n, seed=seed)[0]


def test_the_ensemble_acts_by_the_mean_of_its_members_actions():
    base = _actor()
    members = [base, _perturbed(base, 1), _perturbed(base, 2)]
    ensemble = EnsemblePolicy(members)
    observations = _observations(ensemble)
    for obs in observations:
        each = np.array([m.act(obs) for m in members])
        np.testing.assert_allclose(ensemble.act(obs), each.mean(axis=0), rtol=0, atol=1e-12)
        assert np.all(np.abs(ensemble.act(obs)) <= 1.0)
    # the members differ, or the mean proves little
    assert max(np.abs(members[0].act(o) - members[1].act(o)).max() for o in observations) > 1e-3
    # two copies of one actor act as that actor, exactly
    twins = EnsemblePolicy([base, base])
    for obs in observations:
        np.testing.assert_array_equal(twins.act(obs), base.act(obs))
    flat = np.stack([ensemble.flatten(o) for o in observations])
    np.testing.assert_allclose(ensemble.act_flat(flat), [ensemble.act(o) for o in observations], atol=1e-12)
    assert ensemble.meta["format"] == ENSEMBLE_FORMAT and len(ensemble.meta["members"]) == 3
    assert ensemble.meta["scene"] == "deck1" and ensemble.predictor == base.predictor == "none"
    assert ensemble.scene_overrides == base.scene_overrides


@pytest.mark.slow
def test_an_ensemble_file_round_trips_and_plays_an_episode(tmp_path):
    base = _actor()
    ensemble = EnsemblePolicy([base, _perturbed(base, 1, scale=0.05)])
    path = ensemble.save(tmp_path / "pair.npz")
    assert not list(tmp_path.glob("*.tmp*"))
    loaded = load_actor(path)
    assert isinstance(loaded, EnsemblePolicy) and EnsemblePolicy.load(path).meta == loaded.meta == ensemble.meta
    for obs in _observations(ensemble):
        np.testing.assert_array_equal(loaded.act(obs), ensemble.act(obs))
    # by path, as deck-sim run and eval take it: the environment the members need, one whole episode
    env = deck_sim.load("deck1", seed=1000, **loaded.scene_overrides)
    policy = make_policy(str(path), env)
    assert isinstance(policy, EnsemblePolicy)
    result = run_episode(env, policy, episode=0)
    assert result.outcome in ("goal", "collision", "timeout", "off_surface") and result.steps > 0
    # a single-actor file still loads as one actor
    assert isinstance(load_actor(shipped_policy_path("dqn", "deck1")), LearnedPolicy)


def test_members_that_cannot_act_together_are_refused():
    ddpg, mddpg = _actor("ddpg", "deck2"), _actor("mddpg", "deck2")
    with pytest.raises(PolicyFileError, match="member 1 .* reads observation"):
        EnsemblePolicy([mddpg, ddpg])  # MDDPG also reads the prediction
    with pytest.raises(PolicyFileError, match="head 'argmax'"):
        EnsemblePolicy([_actor("dqn", "deck1"), _actor("dqn", "deck1")])  # a mean of greedy rows is not DQN
    with pytest.raises(PolicyFileError, match="two or more"):
        EnsemblePolicy([ddpg])
    with pytest.raises(PolicyFileError, match="member 1 is a EnsemblePolicy, not one actor"):
        EnsemblePolicy([ddpg, EnsemblePolicy([ddpg, ddpg])])
    other = LearnedPolicy(ddpg.arrays, {**ddpg.meta, "scene_overrides": {
        **ddpg.meta["scene_overrides"], "episode__control_period": 0.4}}, source="<slower>")
    with pytest.raises(PolicyFileError, match="needs scene fields"):
        EnsemblePolicy([ddpg, other])


def test_broken_ensemble_files_give_clear_errors_and_a_failed_save_keeps_the_old_file(tmp_path, monkeypatch):
    base = _actor()
    good = EnsemblePolicy([base, _perturbed(base, 1)]).save(tmp_path / "good.npz")
    with pytest.raises(PolicyFileError, match="ensemble of 2 actors.*load_actor"):
        LearnedPolicy.load(good)
    truncated = tmp_path / "truncated.npz"
    truncated.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    with pytest.raises(PolicyFileError, match="not a readable actor file"):
        load_actor(truncated)

    with np.load(good) as data:
        arrays = {k: data[k] for k in data.files}
    meta = json.loads(str(arrays.pop("meta")))

    def write(name: str, arrays: dict, meta: dict):
        path = tmp_path / name
        write_actor_file(path, arrays, meta, compress=False)
        return path

    missing = {k: v for k, v in arrays.items() if k != "m1/w1"}
    with pytest.raises(PolicyFileError, match="member 1.*not a complete deck_sim actor"):
        load_actor(write("missing.npz", missing, meta))
    for key in ("m2/w0", "m01/w0", "w0"):
        with pytest.raises(PolicyFileError, match=rf"\['{key}'\] belong to no member"):
            load_actor(write("stray.npz", {**arrays, key: arrays["m0/w0"]}, meta))
    nested = {**meta, "members": [meta["members"][0], {**meta["members"][1], "format": ENSEMBLE_FORMAT}]}
    with pytest.raises(PolicyFileError, match="member 1 is itself an ensemble record"):
        load_actor(write("nested.npz", arrays, nested))
    with pytest.raises(PolicyFileError, match="'members' record is not a list"):
        load_actor(write("members.npz", arrays, {**meta, "members": "two"}))
    with pytest.raises(PolicyFileError, match="combine 'median'"):
        load_actor(write("combine.npz", arrays, {**meta, "combine": "median"}))
    nan = {**arrays, "m1/b0": np.full_like(arrays["m1/b0"], np.nan)}
    with pytest.raises(PolicyFileError, match="member 1: the actor holds NaN"):
        load_actor(write("nan.npz", nan, meta))

    before = good.read_bytes()

    monkeypatch.setattr(np, "savez_compressed", _dies_half_way)
    with pytest.raises(OSError, match="disk full"):
        EnsemblePolicy([base, base]).save(good)
    assert good.read_bytes() == before and sorted(p.name for p in tmp_path.glob("good*")) == ["good.npz"]
    assert zipfile.is_zipfile(good)


def test_an_actor_saved_reads_back_the_same_and_a_failed_save_keeps_the_old_file(tmp_path, monkeypatch):
    actor = _actor()
    path = actor.save(tmp_path / "actor.npz")
    back = load_actor(path)
    assert isinstance(back, LearnedPolicy) and back.meta == actor.meta
    assert back.arrays.keys() == actor.arrays.keys()
    assert all(np.array_equal(back.arrays[k], v) for k, v in actor.arrays.items())
    obs = {k: np.linspace(-1.0, 1.0, int(np.prod(shape))).reshape(shape) for k, shape in actor.shapes.items()}
    np.testing.assert_array_equal(back.act(obs), actor.act(obs))
    before = path.read_bytes()

    monkeypatch.setattr(np, "savez_compressed", _dies_half_way)
    with pytest.raises(OSError, match="disk full"):
        _perturbed(actor, 1).save(path)
    assert path.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == ["actor.npz"]


def test_deck_sim_ensemble_joins_actor_files(tmp_path, capsys):
    base = _actor()
    a, b = tmp_path / "a.npz", tmp_path / "b.npz"
    for path, actor in ((a, base), (b, _perturbed(base, 3))):
        write_actor_file(path, actor.arrays, actor.meta, compress=False)
    out = tmp_path / "ab.npz"
    assert cli(["ensemble", str(a), str(b), "--out", str(out)]) == 0
    assert "2 ddpg actors of scene 'deck1'" in capsys.readouterr().out
    joined = load_actor(out)
    assert isinstance(joined, EnsemblePolicy) and [m.meta["config"]["seed"] for m in joined.members] == [0, 3]
    before = a.read_bytes()
    assert cli(["ensemble", str(a), str(b), "--out", str(a)]) == 2  # would overwrite a member
    assert "one of the actors" in capsys.readouterr().err and a.read_bytes() == before
    mddpg = tmp_path / "m.npz"
    m = _actor("mddpg", "deck1")
    write_actor_file(mddpg, m.arrays, m.meta, compress=False)
    assert cli(["ensemble", str(a), str(mddpg), "--out", str(tmp_path / "mixed.npz")]) == 2
    assert "reads observation" in capsys.readouterr().err and not (tmp_path / "mixed.npz").exists()
    assert cli(["ensemble", str(a), str(tmp_path / "nope.npz"), "--out", str(tmp_path / "x.npz")]) == 2
    assert "no such actor file" in capsys.readouterr().err
    # an ensemble given joins by its actors: ab + a is three actors, each weighing one
    assert cli(["ensemble", str(out), str(a), "--out", str(tmp_path / "aba.npz")]) == 0
    assert [m.meta["config"]["seed"] for m in load_actor(tmp_path / "aba.npz").members] == [0, 3, 0]

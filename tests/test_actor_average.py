"""The averaged actor (``actor_average``): a slow Polyak average of the actor's weights that training never reads,
exported at the end of a run as ``actor_avg.npz``, kept in the checkpoint so that a resumed run ends with the same
average."""

from __future__ import annotations

import numpy as np
import pytest

from deck_sim.policies import LearnedPolicy
from tests.conftest import short_config
from tests.training_runs import assert_same_run
from training.checkpoints import load_checkpoint
from training.config import ConfigError, make_config
from training.loop import Trainer


def test_the_rate_is_checked_and_refused_with_the_final_fit():
    for value in (-0.1, 1.0):
        with pytest.raises(ConfigError, match="actor_average: must lie in"):
            make_config("reward", actor_average=value)
    with pytest.raises(ConfigError, match="actor_average: the final fit"):
        make_config("tuned", actor_average=1e-3, polish_epochs=5)
    assert make_config("reward").actor_average == 0.0


@pytest.mark.slow
def test_the_average_changes_no_update_ends_apart_from_the_actor_and_resumes_exactly(tmp_path):
    fields = dict(demo_episodes=0, pretrain_updates=0, bc_weight=0.0, expert_relabel=False, polish_epochs=0)
    plain = Trainer(short_config(**fields), tmp_path / "plain", progress=False)
    plain.train()
    tau = short_config(**fields).tau
    cfg = short_config(**fields, actor_average=tau)
    whole = Trainer(cfg, tmp_path / "whole", progress=False)
    whole.train()
    # training never reads the average: the same updates, the same actor, as without it
    assert_same_run(plain, whole)
    assert not (tmp_path / "plain" / "actor_avg.npz").exists()
    online = np.load(tmp_path / "whole" / "actor.npz")
    averaged = np.load(tmp_path / "whole" / "actor_avg.npz")
    assert set(online.files) == set(averaged.files)
    np.testing.assert_array_equal(online["norm_mean"], averaged["norm_mean"])  # the same normaliser
    assert not np.array_equal(online["w0"], averaged["w0"])
    # at the target networks' rate the average is the target actor, updated after the same actor updates
    target = load_checkpoint(tmp_path / "whole" / "checkpoint.pt")["agent"]["actor_target"]
    for i, layer in enumerate(("net.0", "net.2", "net.4")):
        np.testing.assert_allclose(averaged[f"w{i}"], target[f"{layer}.weight"].numpy(), rtol=0, atol=1e-7)
        np.testing.assert_allclose(averaged[f"b{i}"], target[f"{layer}.bias"].numpy(), rtol=0, atol=1e-7)
    policy = LearnedPolicy.load(tmp_path / "whole" / "actor_avg.npz")
    assert policy.meta["averaged"] == tau and policy.meta["trained_steps"] == cfg.total_steps
    # stopped and resumed, the run ends with the same average
    first = Trainer(cfg, tmp_path / "broken", progress=False)
    first.train(stop_at=70)
    resumed = Trainer(cfg, tmp_path / "broken", resume=True, progress=False)
    resumed.train()
    assert_same_run(whole, resumed)
    again = np.load(tmp_path / "broken" / "actor_avg.npz")
    for k in averaged.files:
        if k != "meta":
            np.testing.assert_array_equal(averaged[k], again[k], err_msg=k)

"""The observation normaliser (``training.networks.RunningNorm``): its running statistics equal those of every
entry it was given, each dimension counting only the entries marked real, and files written when it kept one count
for every dimension still load."""

from __future__ import annotations

import numpy as np
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from training.networks import RunningNorm


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), batches=st.integers(1, 4), dim=st.integers(1, 6))
def test_masked_updates_give_the_statistics_of_the_real_entries_alone(seed, batches, dim):
    rng = np.random.default_rng(seed)
    norm = RunningNorm(dim)
    xs, masks = [], []
    for _ in range(batches):
        n = int(rng.integers(1, 30))
        x = rng.normal(rng.uniform(-50, 50, dim), rng.uniform(0.5, 20, dim), size=(n, dim))
        mask = rng.random((n, dim)) < 0.7
        x[~mask] = 1000.0  # what a padded row holds: it must not reach the statistics
        norm.update(x, mask)
        xs.append(x)
        masks.append(mask)
    x, mask = np.concatenate(xs), np.concatenate(masks)
    for j in range(dim):
        real = x[mask[:, j], j]
        assert norm.count[j].item() == real.size + 1e-4
        if real.size:  # the real entries pooled with the starting state (mean 0, variance 1, count 1e-4)
            n, c = real.size, 1e-4
            mean = real.sum() / (n + c)
            var = (c * 1.0 + n * real.var() + real.mean() ** 2 * c * n / (n + c)) / (n + c)
            np.testing.assert_allclose(norm.mean[j].item(), mean, rtol=1e-9, atol=1e-9)
            np.testing.assert_allclose(norm.var[j].item(), var, rtol=1e-9, atol=1e-9)
        else:  # never seen: as it started
            assert norm.mean[j].item() == 0.0 and norm.var[j].item() == 1.0


def test_without_a_mask_the_statistics_are_those_of_one_shared_count_to_the_last_bit():
    """The update with one count for every dimension, as the normaliser kept it before it counted each apart:
    runs without padding compute the same numbers."""
    rng = np.random.default_rng(0)
    a, b = RunningNorm(5), RunningNorm(5)
    f64 = torch.float64
    mean, var, count = torch.zeros(5, dtype=f64), torch.ones(5, dtype=f64), torch.tensor(1e-4, dtype=f64)
    for _ in range(3):
        x = rng.normal(2.0, 7.0, size=(8, 5))
        a.update(x)
        b.update(x, np.ones_like(x, dtype=bool))
        t = torch.as_tensor(x)
        b_mean, b_var, b_n = t.mean(0), t.var(0, unbiased=False), float(len(x))
        delta = b_mean - mean
        total = count + b_n
        mean = mean + delta * b_n / total
        var = (var * count + b_var * b_n + delta.square() * count * b_n / total) / total
        count = total
    for norm in (a, b):
        assert torch.equal(norm.mean, mean) and torch.equal(norm.var, var)
        assert torch.equal(norm.count, count.expand(5))


def test_a_file_with_one_count_for_every_dimension_loads():
    norm = RunningNorm(3)
    norm.load_state_dict({"mean": torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64),
                          "var": torch.tensor([4.0, 5.0, 6.0], dtype=torch.float64),
                          "count": torch.tensor(250.0, dtype=torch.float64)})
    assert norm.count.tolist() == [250.0, 250.0, 250.0]
    assert norm.mean.tolist() == [1.0, 2.0, 3.0]


def test_tied_rows_with_different_counts_pool_by_count():
    norm = RunningNorm(4)
    norm.tie([np.array([[0, 1], [2, 3]])])  # two rows of two features
    x = np.array([[1.0, 10.0, 5.0, 50.0]] * 3 + [[3.0, 30.0, 0.0, 0.0]])
    mask = np.ones_like(x, dtype=bool)
    mask[3, 2:] = False  # the second row's last entry is padding
    norm.update(x, mask)
    mean, std = norm.stats()
    # feature 0 over both rows' real entries: 1, 1, 1, 3 (row 0) and 5, 5, 5 (row 1)
    real = np.array([1.0, 1.0, 1.0, 3.0, 5.0, 5.0, 5.0])
    np.testing.assert_allclose(mean[0].item(), real.mean(), rtol=1e-4)
    np.testing.assert_allclose(mean[2].item(), real.mean(), rtol=1e-4)
    np.testing.assert_allclose(std[0].item() ** 2, real.var(), rtol=1e-3)

"""Ray datasets: epoch-style drawing of random and sparse-depth rays."""

import torch

from simplenerf.data.datasets import shuffled_pool


def test_sparse_pool_draws_every_entry_once_per_pass():
    batches = shuffled_pool(10, 4, torch.Generator().manual_seed(0))
    drawn = torch.cat([next(batches) for _ in range(5)])  # 20 draws = exactly 2 passes over 10 entries
    assert sorted(drawn[:10].tolist()) == list(range(10)) and sorted(drawn[10:].tolist()) == list(range(10))


def test_pool_smaller_than_a_batch_spans_passes():
    batch = next(shuffled_pool(3, 7, torch.Generator().manual_seed(1)))
    assert len(batch) == 7
    assert sorted(batch[:3].tolist()) == [0, 1, 2] and sorted(batch[3:6].tolist()) == [0, 1, 2]

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


def test_random_rays_continue_after_the_batches_already_drawn(synthetic_scene, monkeypatch):
    """A resumed run's stream (`start_batch`) is the straight stream from that batch on: random and sparse rays, in
    the main process and split over data-loader workers (which take batches in turn)."""
    import itertools
    from types import SimpleNamespace

    from simplenerf.data import datasets
    from simplenerf.data.datasets import RandomRays, SparseDepthPool
    from simplenerf.data.llff import load_llff_scene, subset

    scene = load_llff_scene(synthetic_scene, factor=1, n_views=2)
    views = subset(scene.views, scene.split.train)
    pool = SparseDepthPool(view=torch.tensor([0, 1, 0, 1, 1]), uv=torch.rand(5, 2) * 40, depth=torch.rand(5) + 1,
                           weight=torch.ones(5))

    def stream(start: int, worker=None) -> list:
        monkeypatch.setattr(datasets, "get_worker_info", lambda: worker)
        rays = RandomRays(views, 1000, near=1.0, seed=0, sparse=pool, sparse_rays_per_batch=3, start_batch=start)
        return [(b.random.uv, b.sparse.uv) for b in itertools.islice(iter(rays), 8)]

    def same(a: list, b: list) -> bool:
        return all(torch.equal(x, y) and torch.equal(u, v) for (x, u), (y, v) in zip(a, b, strict=True))

    straight = stream(0)
    assert same(stream(5)[:3], straight[5:8])  # 6144 pixels: batch 6 starts the second permutation
    # Two workers: worker 1 drew batches 1, 3, 5, ... of its own stream; after 5 batches it continues with its third.
    worker1 = SimpleNamespace(id=1, num_workers=2)
    assert same(stream(5, worker1)[:2], stream(0, worker1)[2:4])


def test_random_rays_refuse_counts_that_would_spin(synthetic_scene):
    import pytest

    from simplenerf.data.datasets import RandomRays
    from simplenerf.data.llff import load_llff_scene, subset

    scene = load_llff_scene(synthetic_scene, factor=1, n_views=2)
    views = subset(scene.views, scene.split.train)
    for rays_per_batch in (-64, 0):
        with pytest.raises(ValueError, match="rays_per_batch must be an integer >= 1"):
            RandomRays(views, rays_per_batch, near=1.0)


def test_unseen_patches_are_squares_of_one_camera_each_and_leave_the_other_rays_as_they_were(synthetic_scene):
    """Each batch carries `unseen_patches` patches of size x size rays, each from one camera (one origin), through a
    square of neighbouring pixels (row-major); the random rays are those drawn without them, and a resume continues
    the patches' stream too."""
    import itertools

    import pytest

    from simplenerf.data.datasets import RandomRays
    from simplenerf.data.llff import load_llff_scene, subset
    from simplenerf.geometry.unseen import mean_rotation

    scene = load_llff_scene(synthetic_scene, factor=1, n_views=2)
    views = subset(scene.views, scene.split.train)

    def batches(start: int = 0, **unseen) -> list:
        return list(itertools.islice(iter(RandomRays(views, 256, near=1.0, seed=3, start_batch=start, **unseen)), 6))

    plain, with_patches = batches(), batches(unseen_patches=3, patch_size=4)
    assert all(b.unseen is None for b in plain)
    assert all(torch.equal(a.random.uv, b.random.uv) for a, b in zip(plain, with_patches, strict=True))
    patches = with_patches[0].unseen
    assert patches.size == 4 and patches.count == 3 and len(patches) == 48
    origins = patches.rays.origins.reshape(3, 16, 3)
    assert torch.equal(origins, origins[:, :1].expand(3, 16, 3))  # one camera per patch
    assert not torch.allclose(origins[0, 0], origins[1, 0])  # different cameras
    # Neighbouring pixels of one camera looking along the train cameras' mean axis: in its frame the directions step
    # by 1 / fx along a row and by -1 / fy down a column, at z = -1.
    fx, fy = views.intrinsics[0, 0, 0], views.intrinsics[0, 1, 1]
    camera = patches.rays.directions.reshape(3, 4, 4, 3)[0] @ mean_rotation(views.c2w)  # R^T d, as rows
    assert torch.allclose(camera[..., 2], torch.full((4, 4), -1.0), atol=1e-5)
    assert torch.allclose(torch.diff(camera[..., 0], dim=1), (1 / fx).expand(4, 3), atol=1e-5)
    assert torch.allclose(torch.diff(camera[..., 1], dim=0), (-1 / fy).expand(3, 4), atol=1e-5)
    resumed = batches(start=2, unseen_patches=3, patch_size=4)
    assert torch.equal(resumed[0].unseen.rays.origins, with_patches[2].unseen.rays.origins)
    with pytest.raises(ValueError, match="unseen patches of 9 px need at least 2 train views"):
        RandomRays(subset(views, [0]), 64, near=1.0, unseen_patches=1, patch_size=9)

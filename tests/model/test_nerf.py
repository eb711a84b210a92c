import math

import pytest
import torch

from simplenerf.geometry.rays import RayBundle, make_rays
from simplenerf.model.nerf import NeRF, mlp_nerf

K = torch.tensor([[[40.0, 0.0, 16.0], [0.0, 40.0, 12.0], [0.0, 0.0, 1.0]]])
C2W = torch.cat([torch.eye(3), torch.zeros(3, 1)], dim=1)[None]


def rays(n: int = 32) -> RayBundle:
    uv = torch.stack([torch.arange(n) % 32, torch.arange(n) // 32], dim=-1)
    return make_rays(K, C2W, uv, 32, 24, near=1.0)


def small_nerf() -> NeRF:
    torch.manual_seed(0)
    return mlp_nerf(num_coarse=16, num_fine=8, num_layers=3, width=32, skip_layer=2)


def test_forward_shapes_and_fine_samples():
    nerf = small_nerf()
    out = nerf(rays(), randomized=True)
    assert out.coarse.rgb.shape == (32, 3) and out.fine.depth.shape == (32,)
    assert out.coarse.weights.shape == (32, 16) and out.fine.weights.shape == (32, 24)
    assert out.coarse_samples.encoded_positions(10).shape == (32, 16, 63)
    assert torch.equal(out.fine_samples.encoded_directions(4), out.coarse_samples.encoded_directions(4))


def test_depth_lies_between_near_plane_and_far_samples():
    out = small_nerf()(rays(), randomized=False)
    t = out.fine_samples.t_metric
    acc = out.fine.accumulation
    # depth = sum(w t) / (sum(w) + 1e-6) is a weighted mean of the sample depths.
    assert bool((out.fine.depth <= t.max(-1).values * acc / (acc + 1e-6) + 1e-3).all())
    assert bool((out.fine.depth >= t.min(-1).values * acc / (acc + 1e-6) - 1e-3).all())


def test_chunked_rendering_equals_one_pass_and_is_deterministic():
    nerf = small_nerf().eval()
    r = rays(64)
    with torch.no_grad():
        whole = nerf(r, randomized=False)
    chunked = nerf.render_rays_chunked(r, chunk=10)
    assert torch.allclose(chunked.rgb, whole.fine.rgb, atol=1e-6)
    assert torch.allclose(chunked.depth, whole.fine.depth, atol=1e-5)
    assert torch.equal(nerf.render_rays_chunked(r, chunk=64).rgb, nerf.render_rays_chunked(r, chunk=64).rgb)


def test_chunked_rendering_frees_each_chunks_samples_before_the_next():
    """Memory bounded at any resolution: when a chunk is rendered, the per-sample weights of the chunks before it are
    gone (only their per-ray results are kept). Keeping them cost 18 GiB on a 1008x756 frame with 192 samples a ray."""
    import weakref

    nerf = small_nerf().eval()
    forward, earlier, alive_at_each_chunk = nerf.forward, [], []

    def recording_forward(*args, **kwargs):
        alive_at_each_chunk.append(sum(ref() is not None for ref in earlier))
        out = forward(*args, **kwargs)
        earlier.extend(weakref.ref(t) for t in (out.coarse.weights, out.fine.weights, out.fine_samples.positions))
        return out

    nerf.forward = recording_forward
    chunked = nerf.render_rays_chunked(rays(64), chunk=10)
    assert alive_at_each_chunk == [0] * 7
    assert chunked.rgb.shape == (64, 3) and chunked.depth.shape == (64,)


def test_gradients_reach_both_fields():
    nerf = small_nerf()
    out = nerf(rays(), randomized=True)
    (out.coarse.rgb.sum() + out.fine.rgb.sum()).backward()
    assert nerf.coarse.trunk[0].weight.grad.abs().sum() > 0
    assert nerf.fine.trunk[0].weight.grad.abs().sum() > 0


def test_field_chunks_give_the_same_renders_and_share_one_encoding():
    whole, chunked = small_nerf(), small_nerf()
    chunked.field_chunk = 16 * 5  # 5 rays of 16 coarse samples per field call
    r = rays()
    torch.manual_seed(1)
    a = whole(r, randomized=True)
    torch.manual_seed(1)
    b = chunked(r, randomized=True)
    assert torch.allclose(a.coarse.rgb, b.coarse.rgb, atol=1e-6)
    assert torch.allclose(a.fine.depth, b.fine.depth, atol=1e-5)
    # The pieces' encodings are views of one encoding of all the samples, computed once.
    piece = b.coarse_samples[0:5]
    assert piece.encoded_positions(10).data_ptr() == b.coarse_samples.encoded_positions(10).data_ptr()
    assert torch.equal(piece.encoded_positions(10), b.coarse_samples.encoded_positions(10)[0:5])


class ConstantField(torch.nn.Module):
    """Density ln 2 everywhere (alpha 1/2 per unit interval), grey colour."""

    def forward(self, samples):
        from simplenerf.model.fields import FieldOutputs

        r, s = samples.t.shape
        return FieldOutputs(torch.full((r, s), math.log(2.0)), torch.full((r, s, 3), 0.5))


def test_render_with_a_near_cut_is_empty_in_front_of_it():
    from simplenerf.model.samples import Samples

    nerf = small_nerf()
    t = torch.tensor([[0.0, 0.125, 0.25, 0.5]])  # NDC z = -1 + 2 t: -1, -0.75, -0.5, 0
    positions = torch.stack([torch.zeros_like(t), torch.zeros_like(t), -1.0 + 2.0 * t], dim=-1)
    t_metric = torch.tensor([[1.0, 1.2, 1.5, 2.0]])
    samples = Samples(t=t, t_metric=t_metric, delta=torch.ones_like(t), positions=positions,
                      directions=torch.tensor([[0.0, 0.0, -1.0]]))
    whole = nerf.render(ConstantField(), samples, randomized=False)
    cut = nerf.render(ConstantField(), samples, randomized=False, min_ndc_z=-0.5)
    torch.testing.assert_close(whole.weights, torch.tensor([[0.5, 0.25, 0.125, 0.0625]]))
    torch.testing.assert_close(cut.weights, torch.tensor([[0.0, 0.0, 0.5, 0.25]]))  # alphas 0, 0, 1/2, 1/2
    torch.testing.assert_close(cut.depth, torch.tensor([(0.5 * 1.5 + 0.25 * 2.0) / (0.75 + 1e-6)]))


def test_the_chunked_renderer_renders_augmented_depths_and_can_be_abandoned():
    """The one full-frame renderer: an augmentation's depth at the main samples, as `aug.render` gives it on the whole
    batch; `before_chunk` runs before each chunk, and what it raises abandons the render."""
    from simplenerf.method.augmentations import Augmentation
    from simplenerf.model.fields import RadianceField

    nerf = small_nerf().eval()
    aug = Augmentation("views", RadianceField(view_dependent=False, num_layers=2, width=16, skip_layer=None), None)
    r = rays(64)
    calls = []
    chunked = nerf.render_rays_chunked(r, chunk=10, augmentations=[aug], before_chunk=lambda: calls.append(1))
    assert len(calls) == 7 and set(chunked.augmented_depth) == {"views"}
    with torch.no_grad():
        expected = aug.render(nerf, nerf(r, randomized=False), False).depth
    assert torch.allclose(chunked.augmented_depth["views"], expected, atol=1e-5)
    assert torch.equal(chunked.depth_of("views"), chunked.augmented_depth["views"])
    assert torch.equal(chunked.depth_of("coarse"), chunked.coarse_depth)
    assert chunked.reshape(8, 8).augmented_depth["views"].shape == (8, 8)

    class Stop(Exception):
        pass

    def stop_at_third() -> None:
        calls.append(1)
        if len(calls) == 10:
            raise Stop

    with pytest.raises(Stop):
        nerf.render_rays_chunked(r, chunk=10, before_chunk=stop_at_third)
    assert len(calls) == 10  # 7 of the first render, then the third chunk of this one

"""The figures of benchmarks/quality/ that score a run's maps and masks: texture printed into depth
(benchmarks.quality.texture_in_depth) on a hand-made plane with one edge, and streaks along the image axes
(benchmarks.quality.streak_index) on hand-made maps, a reliability mask against SfM depth
(benchmarks.quality.mask_accuracy) on hand-made depths, and the views' registration (benchmarks.quality.registration)
on the synthetic scene's exact depth."""

import cv2
import numpy as np
import pytest
import torch

from benchmarks.quality.mask_accuracy import pair_scores
from benchmarks.quality.registration import registration
from benchmarks.quality.streak_index import axis_ratio, matched_blur, streak_index, strip_ratios
from benchmarks.quality.texture_in_depth import flat_pixels, score
from simplenerf.data.llff import load_llff_scene, subset
from simplenerf.sfm.sparse_depth import SparseDepth


def test_flat_pixels_are_those_whose_neighbourhood_is_on_one_plane():
    rows, cols = np.mgrid[0:8, 0:8].astype(float)
    exact = 1.0 / (0.5 + 0.01 * rows + 0.02 * cols)  # one plane: inverse depth affine in the pixel
    assert flat_pixels(exact, 1e-3)[1:-1, 1:-1].all() and not flat_pixels(exact, 1e-3)[0].any()
    exact[:, 5:] = 4.0  # a second plane from column 5: its border columns 4 and 5 are not flat
    flat = flat_pixels(exact, 1e-3)
    assert flat[1:-1, [1, 2, 3, 6]].all() and not flat[:, [4, 5]].any()


def test_texture_printed_into_depth_makes_the_error_jump_at_the_photos_edges():
    exact = np.full((8, 8), 2.0)  # a fronto-parallel plane
    grey = np.zeros((8, 8))
    grey[:, 4:] = 1.0  # one vertical edge between columns 3 and 4
    image = np.repeat(grey[..., None], 3, axis=-1)
    cols = np.mgrid[0:8, 0:8][1].astype(float)
    assert score(exact, exact, image, 1e-3, 0.2)["flat_roughness"] == 0.0
    # relative error e = 0.1 grey (the texture) + 0.01 col (a smooth tilt): |grad e| is 0.01 on the plain pixels,
    # 0.1 / 2 + 0.01 on the 12 flat pixels of columns 3 and 4 (the edge's, the top 20% of the flat pixels' edges)
    depth = exact * (1.0 + 0.1 * grey + 0.01 * cols)
    s = score(depth, exact, image, 1e-3, 0.2)
    assert s["textured_roughness"] == pytest.approx(0.06) and s["plain_roughness"] == pytest.approx(0.01)
    assert s["flat_roughness"] == pytest.approx((12 * 0.06 + 24 * 0.01) / 36)
    assert s["flat_error"] == pytest.approx(0.01 * 3.5 + 0.1 * 0.5)  # interior columns 1-6, grey 1 on 4-6
    assert s["flat_fraction"] == pytest.approx(36 / 64)


def test_axis_ratio_is_the_row_over_the_column_variation():
    rows, cols = np.mgrid[0:6, 0:9].astype(float)
    assert axis_ratio(2.0 * rows + cols) == pytest.approx(2.0)
    assert axis_ratio(np.repeat((rows + cols)[..., None], 3, axis=-1)) == pytest.approx(1.0)


def test_streak_index_divides_by_the_photos_ratio(tmp_path):
    rows, cols = np.mgrid[0:6, 0:9].astype(float)
    photo = np.repeat((10.0 * rows + 20.0 * cols)[..., None], 3, axis=-1).astype(np.uint8)  # ratio 0.5
    photos = [tmp_path / f"{i:03d}.png" for i in range(3)]
    for path in photos:
        cv2.imwrite(str(path), photo)
    run = tmp_path / "run"
    (run / "test" / "depth").mkdir(parents=True)
    (run / "test" / "rgb").mkdir()
    np.save(run / "test" / "depth" / "image002.npy", 3.0 * rows + cols)  # ratio 3: smeared along rows
    cv2.imwrite(str(run / "test" / "rgb" / "image002.png"), photo)
    assert streak_index(run, photos) == pytest.approx({"depth": 6.0, "render": 1.0, "frames": 1})
    named = tmp_path / "DJI_1.png"  # matched by name first
    cv2.imwrite(str(named), np.ascontiguousarray(photo.transpose(1, 0, 2)))  # ratio 2
    np.save(run / "test" / "depth" / "DJI_1.npy", 3.0 * rows + cols)
    cv2.imwrite(str(run / "test" / "rgb" / "DJI_1.png"), photo)
    assert streak_index(run, [*photos, named]) == pytest.approx({"depth": (6.0 + 1.5) / 2, "render": 0.625,
                                                                 "frames": 2})


def test_strip_ratios_place_the_streaks_across_the_frame(tmp_path):
    rows, cols = np.mgrid[0:6, 0:8].astype(float)
    depth = rows + cols  # ratio 1 everywhere ...
    depth[:, 4:] = 3.0 * rows[:, 4:] + cols[:, 4:]  # ... but 3 in the right half: smeared along rows there
    assert strip_ratios(depth, 2) == pytest.approx([1.0, 3.0])
    assert strip_ratios(depth, 4) == pytest.approx([1.0, 1.0, 3.0, 3.0])  # each strip's own columns only
    with pytest.raises(SystemExit, match="at least 2 columns"):
        strip_ratios(depth, 5)
    photo = np.repeat((10.0 * rows + 20.0 * cols)[..., None], 3, axis=-1).astype(np.uint8)  # ratio 0.5 in each strip
    cv2.imwrite(str(tmp_path / "000.png"), photo)
    run = tmp_path / "run"
    (run / "test" / "depth").mkdir(parents=True)
    (run / "test" / "rgb").mkdir()
    np.save(run / "test" / "depth" / "image000.npy", depth)
    cv2.imwrite(str(run / "test" / "rgb" / "image000.png"), photo)
    index = streak_index(run, [tmp_path / "000.png"], strips=2)
    assert index["depth_strips"] == pytest.approx([2.0, 6.0]) and index["render_strips"] == pytest.approx([1.0, 1.0])
    assert index["depth"] == pytest.approx(axis_ratio(depth) / 0.5)  # the whole frame's index is unchanged


def test_the_matched_index_tells_blur_from_a_smear_along_rows(tmp_path):
    """Blur alone raises the plain index of a photo whose fine texture is isotropic and whose large-scale structure runs
    along rows; against the photo blurred as much, a blurred render is at 1 and a smeared one stays above."""
    rows = np.mgrid[0:60, 0:80][0].astype(float)
    texture = np.random.default_rng(0).random((60, 80)) * 80.0  # isotropic fine texture
    photo = np.repeat((60.0 + texture + 20.0 * np.sin(rows / 10.0))[..., None], 3, axis=-1).astype(np.uint8)
    blurred = cv2.GaussianBlur(photo, (0, 0), 2.0)
    smeared = cv2.blur(photo, (9, 1))  # 9 px along rows
    sigma, soft = matched_blur(photo, blurred)
    assert sigma == pytest.approx(2.0, abs=0.05) and soft.shape == photo.shape
    assert matched_blur(photo, photo)[0] == 0.0 and (matched_blur(photo, photo)[1] == photo).all()
    assert matched_blur(photo, np.full_like(photo, 9), max_sigma=4.0)[0] == 4.0  # a flat render: the largest blur
    cv2.imwrite(str(tmp_path / "000.png"), photo)
    for name, render in (("blurred", blurred), ("smeared", smeared)):
        run = tmp_path / name
        (run / "test" / "depth").mkdir(parents=True)
        (run / "test" / "rgb").mkdir()
        np.save(run / "test" / "depth" / "image000.npy", render.mean(axis=-1))
        cv2.imwrite(str(run / "test" / "rgb" / "image000.png"), render)
    plain = streak_index(tmp_path / "blurred", [tmp_path / "000.png"], matched=True)
    assert plain["render"] > 1.4  # the plain index counts this blur as a streak ...
    assert plain["render_matched"] == pytest.approx(1.0, abs=0.03)  # ... the matched one does not
    assert plain["depth_matched"] == pytest.approx(plain["render_matched"])  # the depth takes its render's blur
    assert plain["matched_sigma"] == pytest.approx(2.0, abs=0.05)
    smear = streak_index(tmp_path / "smeared", [tmp_path / "000.png"], strips=2, matched=True)
    assert smear["render_matched"] > 2.0 and len(smear["render_strips_matched"]) == 2
    assert smear["render"] == pytest.approx(axis_ratio(smeared) / axis_ratio(photo))  # the plain index unchanged


def test_blur_calibration_degrades_as_named():
    from benchmarks.quality.blur_calibration import degraded

    photo = np.zeros((16, 24, 3), np.uint8)
    photo[:, 10] = 200  # one bright column
    copies = degraded(photo)
    assert (copies["shift2"][:, 12] == 200).all() and (copies["shift2"][:, 10] == 0).all()  # moved 2 px right
    assert (copies["rowblur9"][:, 6:15] > 0).all() and (copies["rowblur9"][:, :6] == 0).all()  # smeared along rows
    assert (copies["gauss1"][0] == copies["gauss1"][-1]).all()  # a column stays a column
    flat = np.full((16, 24, 3), 77, np.uint8)
    assert all((c == 77).all() for c in degraded(flat).values())  # nothing to lose in a flat picture


def test_ray_spread_is_zero_for_a_surface_and_about_a_uniform_fogs_std():
    from types import SimpleNamespace

    import torch

    from benchmarks.quality.view_scores import ray_spread

    t = torch.linspace(0, 1, 101)[:-1].expand(4, 100)
    # rays along NDC z at x = 0.2, except that they move 0.5 in x per unit of t (a camera moved sideways), y = -0.1
    positions = torch.stack([0.2 + 0.5 * t, torch.full_like(t, -0.1), 2 * t - 1], dim=-1)
    surface = torch.zeros(4, 100)
    surface[:, 30] = 0.9  # accumulation 0.9: normalised away
    fog = torch.full((4, 100), 0.01)

    def model_with(weights):
        outputs = SimpleNamespace(fine_samples=SimpleNamespace(t=t, positions=positions),
                                  fine=SimpleNamespace(weights=weights))
        return SimpleNamespace(nerf=lambda rays, randomized: outputs)

    frame = SimpleNamespace(rays=torch.arange(4), width=200, height=100)
    assert ray_spread(model_with(surface), frame, every=1) == {"spread_t": 0.0, "off_surface": 0.0,
                                                                "footprint_x_px": 0.0, "footprint_y_px": 0.0}
    spread = ray_spread(model_with(fog), frame, every=1)
    uniform_std = (1 / 12 - 1 / 12 / 100**2) ** 0.5  # of the discrete uniform t
    assert spread["spread_t"] == pytest.approx(uniform_std, rel=1e-4)
    assert spread["off_surface"] == pytest.approx(0.89, abs=0.011)  # all but the 10 or 11 samples within 0.05
    assert spread["footprint_x_px"] == pytest.approx(0.5 * uniform_std * 100, rel=1e-4)  # 0.5 x per t, 100 px per NDC x
    assert spread["footprint_y_px"] == pytest.approx(0.0, abs=1e-5)


def test_surface_render_takes_the_colour_at_the_median_of_the_weights():
    from types import SimpleNamespace

    import torch

    from benchmarks.quality.view_scores import surface_render

    t = torch.linspace(0, 1, 11).expand(6, 11)  # 6 rays (a 2 x 3 frame), 11 samples from t 0 to 1
    weights = torch.zeros(6, 11)
    weights[:3, 3] = 1.0  # a surface at t 0.3
    weights[3:] = 0.05  # a fog: the median of its weights at t 0.5
    outputs = SimpleNamespace(fine_samples=SimpleNamespace(t=t),
                              fine=SimpleNamespace(weights=weights, rgb=torch.full((6, 3), 0.7),
                                                   depth=torch.arange(6.0)))

    class Nerf:  # the field's colour is t in every channel
        fine = None

        def __call__(self, rays, randomized):
            return SimpleNamespace(fine_samples=SimpleNamespace(t=t[rays]),
                                   fine=SimpleNamespace(weights=weights[rays], rgb=outputs.fine.rgb[rays],
                                                        depth=outputs.fine.depth[rays]))

        def make_samples(self, rays, t_points):
            return t_points

        def evaluate(self, field, samples):
            return SimpleNamespace(rgb=samples[..., None].expand(*samples.shape, 3))

    frame = SimpleNamespace(rays=torch.arange(6), height=2, width=3)
    composite, surface, depth = surface_render(SimpleNamespace(nerf=Nerf()), frame, chunk=4)  # chunks of 4 and 2 rays
    assert composite.shape == surface.shape == (2, 3, 3) and bool((composite == 0.7).all())
    assert torch.equal(depth, torch.arange(6.0).reshape(2, 3))  # the render's own depth, the chunks in order
    assert torch.allclose(surface[0], torch.full((3, 3), 0.3)) and torch.allclose(surface[1], torch.full((3, 3), 0.5))


def test_demo_picture_lays_out_the_panels_with_or_without_exact_depth():
    from benchmarks.quality.demo_picture import row

    rows, cols = np.mgrid[0:8, 0:12].astype(float)
    photo = np.repeat((20 * cols)[..., None], 3, axis=-1).astype(np.uint8)
    depth = 1.0 + rows + cols
    with_exact = row(photo, photo, depth, depth, exact=depth, zoom=2)  # DS-NeRF's depth
    assert with_exact.shape == (22 + 16, 5 * 24 + 4 * 4, 3)  # label bar + 2x panels, 4-px gaps
    llff = row(photo, photo, depth, np.zeros_like(photo), zoom=1, shrink=2)  # DS-NeRF's render
    assert llff.shape == (22 + 4, 4 * 6 + 3 * 4, 3)  # photo | SimpleNeRF | its depth | DS-NeRF, shrunk 2x
    ds_panel = llff[22:, 3 * (6 + 4):]
    assert (ds_panel == 0).all()  # the last panel is DS-NeRF's render, not a depth
    assert (llff[22:, 6:10] == 255).all()  # the gap


def test_a_depth_is_coloured_over_its_own_inverse_depth_percentiles_unless_given_a_range():
    from simplenerf.viz.pictures import colorize_depth, inverse_depth_range

    depth = np.linspace(1.0, 10.0, 200).reshape(10, 20)
    lo, hi = inverse_depth_range(depth)
    assert (lo, hi) == (np.percentile(1 / depth, 1), np.percentile(1 / depth, 99))
    own = colorize_depth(depth)
    assert np.array_equal(own, colorize_depth(depth, lo, hi))
    assert np.array_equal(own[0, 0], colorize_depth(np.array([[0.5]]), lo, hi)[0, 0])  # nearest: clipped to the top
    assert not np.array_equal(own, colorize_depth(depth, lo, 2 * hi))


def test_mask_precision_counts_where_the_chosen_depth_is_the_closer_one():
    z_sfm = np.full(6, 10.0)
    z_main = np.array([10.0, 10.0, 12.0, 10.1, 13.0, 10.0])
    z_other = np.array([11.0, 9.0, 10.0, 10.0, 10.0, 10.5])  # closer to SfM on rays 2, 3 and 4
    mask = np.array([1, -1, 1, 1, -1, 0])  # +1 right on rays 2 and 3, wrong on 0; -1 right on 1, wrong on 4
    s = pair_scores(z_main, z_other, z_sfm, mask, disagree=0.05)
    assert s["rays"] == 6 and s["oracle_other_closer"] == pytest.approx(3 / 6)
    assert (s["share_plus"], s["share_minus"], s["share_zero"]) == pytest.approx((3 / 6, 2 / 6, 1 / 6))
    assert s["precision_plus"] == pytest.approx(2 / 3) and s["precision_minus"] == pytest.approx(1 / 2)
    assert s["error_main_plus"] == pytest.approx((0.0 + 0.2 + 0.01) / 3)
    assert s["error_other_plus"] == pytest.approx((0.1 + 0.0 + 0.0) / 3)
    assert (s["error_main_minus"], s["error_other_minus"]) == pytest.approx(((0.0 + 0.3) / 2, (0.1 + 0.0) / 2))
    # the depths differ by more than 5% of the SfM depth on rays 0, 1, 2, 4 (not 3: 1%, nor 5: exactly 5%)
    apart = s["disagree"]
    assert apart["share"] == pytest.approx(4 / 6) and apart["rays"] == 4
    assert apart["precision_plus"] == pytest.approx(1 / 2) and apart["precision_minus"] == pytest.approx(1 / 2)
    assert np.isnan(pair_scores(z_main[:1], z_other[:1], z_sfm[:1], np.zeros(1, int))["precision_plus"])


def test_registration_is_the_distance_from_the_projected_keypoint_to_the_observed_one(synthetic_scene):
    scene = load_llff_scene(synthetic_scene, factor=1, n_views=2)
    views = subset(scene.views, scene.split.train)
    uv = torch.tensor([[20.0, 15.0], [30.5, 22.0], [40.0, 30.25]], dtype=views.c2w.dtype)
    depth = views.depths[0, uv[:, 1].long(), uv[:, 0].long()]
    rays = views.rays(torch.zeros(3, dtype=torch.long), uv, near=1.0)
    uv_b, z_b = views.project(rays.origins + depth[:, None] * rays.directions, torch.ones(3, dtype=torch.long))

    def seen(pixels, z, ids):
        return SparseDepth(np.asarray(pixels, np.float32), np.asarray(z, np.float32), np.zeros(len(ids), np.float32),
                           np.asarray(ids, np.int64))

    a = seen(uv.numpy(), depth.numpy(), [7, 8, 9])
    # view 1 observed points 8 and 9 where they project, 3 px right and 4 px down of it; point 5 only it saw
    b = seen(np.concatenate([uv_b[1:].numpy() + [3.0, 4.0], [[1.0, 1.0]]]), np.concatenate([z_b[1:].numpy(), [2.0]]),
             [8, 9, 5])
    assert views.nearest.tolist() == [1, 0]
    distances = registration(views, [a, b], near=1.0)
    # each common point from both sides: a -> b is 5 px exactly; b -> a (b's shifted keypoint at b's depth) is not 0
    assert len(distances) == 4 and distances[:2] == pytest.approx([5.0, 5.0], abs=1e-3)
    assert (distances[2:] > 1.0).all()
    shifted = seen(uv_b[1:].numpy(), z_b[1:].numpy(), [8, 9])
    assert registration(views, [a, shifted], near=1.0) == pytest.approx(np.zeros(4), abs=1e-3)


def test_mask_accuracy_scores_the_trained_augmentations_and_l_cfc():
    """`masked_pairs`: each augmentation's pair with the main depth of its stage and L_cfc's (main coarse, fine);
    an augmentation named untrained (retired from step 0: its field as initialised) is left out."""
    from benchmarks.quality.mask_accuracy import masked_pairs
    from simplenerf.method.augmentations import Augmentation
    from simplenerf.method.module import SimpleNeRF
    from simplenerf.method.objective import Objective
    from simplenerf.method.reliability import PatchReprojectionMask
    from simplenerf.model.fields import RadianceField
    from simplenerf.model.nerf import mlp_nerf

    size = {"num_layers": 2, "width": 8, "skip_layer": 1}
    cfc, points = PatchReprojectionMask(), PatchReprojectionMask(min_texture=0.02)
    augs = [Augmentation("points", RadianceField(density_bands=3, **size), points, stage="fine"),
            Augmentation("views", RadianceField(view_dependent=False, **size))]
    model = SimpleNeRF(mlp_nerf(num_coarse=4, num_fine=4, **size), augmentations=augs,
                       objective=Objective(coarse_fine_mask=cfc))
    pairs = masked_pairs(model)
    assert [(name, main, other) for name, _, main, other in pairs] == [
        ("points", "fine", "points"), ("views", "coarse", "views"), ("cfc", "coarse", "fine")]
    assert pairs[0][1] is points and pairs[2][1] is cfc
    assert [name for name, *_ in masked_pairs(model, untrained={"points", "views"})] == ["cfc"]


def test_ndc_extent_reaches_past_the_box_by_a_shifted_cameras_near_plane_disparity():
    from benchmarks.quality.ndc_extent import frame_index, frustum_extent, outside_share, surface_ndc
    from simplenerf.geometry.views import Views

    h, w, f, near, shift = 6, 8, 10.0, 1.0, 0.2
    intrinsics = torch.tensor([[f, 0.0, (w - 1) / 2], [0.0, f, (h - 1) / 2], [0.0, 0.0, 1.0]]).expand(2, 3, 3)
    c2w = torch.eye(4)[:3].repeat(2, 1, 1)
    c2w[1, 0, 3] = shift  # the second camera moved sideways, looking the same way
    views = Views(images=torch.zeros(2, h, w, 3), intrinsics=intrinsics, c2w=c2w, names=["a", "b"])
    extent = frustum_extent(views, near)
    # the reference camera's image is NDC [-1, 1] at every depth; the moved one's reaches 2 f b / (W near) past it
    # at the near plane (and its corners are back at +-1 at infinity)
    torch.testing.assert_close(extent[0], torch.tensor([-1.0, 1.0, -1.0, 1.0]))
    torch.testing.assert_close(extent[1], torch.tensor([-1.0, 1.0 + 2 * f * shift / (w * near), -1.0, 1.0]))
    depth = np.full((h, w), 2.0)
    xy = surface_ndc(views, 1, depth)
    u = np.arange(w)
    np.testing.assert_allclose(xy[0, :, 0], 2 * f / w * (shift / 2.0 + (u - (w - 1) / 2) / f), rtol=1e-5)
    np.testing.assert_allclose(surface_ndc(views, 0, depth)[:, 0, 1], -(np.arange(h) - (h - 1) / 2) * 2 / h,
                               rtol=1e-5)  # rows run down, NDC y up
    # of the moved camera's columns only the rightmost lies past x = 1 (at 2 f b / (W D) + (W - 1) / W = 1.125): a box
    # of 1.0 leaves it, one of 1.5 keeps every pixel
    np.testing.assert_allclose(xy[:, -2:, 0], np.array([[0.875, 1.125]] * h), rtol=1e-5)
    assert outside_share(xy, (1.0, 1.0), 2) == [0.0, pytest.approx(1 / 4)]
    assert outside_share(xy, (1.5, 1.5), 2) == [0.0, 0.0]
    # a rendered map is matched to its frame by file name, else by the index its name ends with
    names = ["DJI_1.JPG", "DJI_0.JPG", "x.png"]
    assert frame_index("DJI_0", names) == 1 and frame_index("image002", names) == 2
    with pytest.raises(SystemExit, match="image009"):
        frame_index("image009", names)

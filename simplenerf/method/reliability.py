"""Reliable depth estimates (Sec. 4.2): patch reprojection errors, the ternary mask and the masked depth losses.

Two models render a depth for the same training ray: the "main" one (the main coarse NeRF) and the "other" one (an
augmented model, or the main fine NeRF for the coarse-fine consistency loss). Each depth is judged by how well it
explains the nearest other training view, and the better, good-enough one supervises the worse through a
stop-gradient (paper eqs. 3, 4 and 7).

Naming, used throughout:
- V train views, R rays, H x W images; k = `patch_size` (odd), h = k // 2 the patch half-width.
- For ray r: a = view[r] is its (train) view, b = nearest[a] the train view with the closest camera centre.
- z: camera z-depth along a ray, so the 3D point is X = o + z d with the un-normalised directions of
  `geometry.rays`. Pixels uv are (column, row) in the `geometry.rays` convention (integer = pixel centre).
- e: patch reprojection error, the RMSE over the k * k * 3 values of two RGB patches (images in [0, 1]).
- m: the ternary mask, +1 = train main toward sg(other), -1 = train other toward sg(main), 0 = neither;
  sg = stop-gradient (detach).
"""

from __future__ import annotations

import abc
import math
from typing import Literal

import torch
import torch.nn.functional as F

from simplenerf.data.batches import RayBatch
from simplenerf.geometry.views import Views, nearest_views

__all__ = [
    "PatchReprojectionMask", "ReliabilityMask", "ReprojectionErrors", "TrustAll", "mask_fractions",
    "masked_depth_loss", "nearest_views", "patch_reprojection_error", "ternary_mask",
]  # fmt: skip

Direction = Literal["bidirectional", "one_way"]


def _patch_offsets(patch_size: int, device: torch.device) -> torch.Tensor:
    """[k * k, 2] integer (du, dv) offsets of a k x k patch around its centre, row-major."""
    half = patch_size // 2
    steps = torch.arange(-half, half + 1, device=device)
    dv, du = torch.meshgrid(steps, steps, indexing="ij")
    return torch.stack([du.flatten(), dv.flatten()], dim=-1)


def _check_patch_size(patch_size: int) -> None:
    if patch_size < 1 or patch_size % 2 == 0:
        raise ValueError(
            f"patch_size must be a positive odd integer (the patch is centred on a pixel), got {patch_size}"
        )


def _centre_pixels(uv: torch.Tensor, height: int, width: int, half: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Rounds continuous pixels to patch centres that are always safe to gather, and says which were inside.

    Args:
        uv: [R, 2] pixel coordinates (column, row), any real dtype; may hold NaN or inf.

    Returns:
        centre [R, 2] long, clamped so that its whole patch lies in the image; inside [R] bool, True where the
        rounded pixel is at least `half` pixels inside the image (False for NaN).
    """
    rounded = torch.round(uv)
    low = torch.tensor([[half, half]], dtype=rounded.dtype, device=rounded.device)
    high = torch.tensor([[width - 1 - half, height - 1 - half]], dtype=rounded.dtype, device=rounded.device)
    inside = ((rounded >= low) & (rounded <= high)).all(dim=-1)
    # Clamp before the cast: float -> long of NaN or of a huge value is undefined and could index out of bounds.
    centre = torch.minimum(torch.maximum(torch.nan_to_num(rounded, nan=float(half)), low), high).long()
    return centre, inside


def _gather_patches(images: torch.Tensor, view: torch.Tensor, centre: torch.Tensor, patch_size: int) -> torch.Tensor:
    """k x k RGB patches of images [V, H, W, 3] around in-bounds centres [R, 2] of views [R] -> [R, k * k, 3]."""
    pixels = centre[:, None, :] + _patch_offsets(patch_size, centre.device)  # [R, k*k, 2]
    return images[view[:, None], pixels[..., 1], pixels[..., 0]]


def _source_patches(
    images: torch.Tensor, view: torch.Tensor, uv: torch.Tensor, patch_size: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """Patches around the rays' own pixels: [R, k * k, 3] and whether each fits in its image [R]."""
    centre, inside = _centre_pixels(uv, images.shape[1], images.shape[2], patch_size // 2)
    return _gather_patches(images, view, centre, patch_size), inside


def _patch_rmse(source: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """RMSE over the k * k * 3 values of patches [R, k * k, 3] -> [R]."""
    return (source - target).square().mean(dim=(1, 2)).sqrt()


def patch_texture(patches: torch.Tensor) -> torch.Tensor:
    """How much texture k x k RGB patches [R, k * k, 3] hold: the standard deviation over the patch's pixels, averaged
    over the channels -> [R]. A plain patch (a white wall) matches every plain patch it lands on, so its reprojection
    error cannot tell a right depth from a wrong one."""
    return patches.std(dim=1, unbiased=False).mean(dim=-1)


def _reprojection_error(
    views: Views, rays: RayBatch, depth: torch.Tensor, source: torch.Tensor, inside: torch.Tensor, patch_size: int,
    require_in_front: bool = True, search_radius: int = 0,
) -> tuple[torch.Tensor, torch.Tensor]:
    """`patch_reprojection_error` given the already gathered source patches [R, k * k, 3] and their validity [R]."""
    target_view = views.nearest[rays.view]
    points = rays.rays.origins + depth.detach()[:, None] * rays.rays.directions
    uv_target, z_target = views.project(points, target_view)
    centre, target_inside = _centre_pixels(uv_target, views.height, views.width, patch_size // 2)
    error = _patch_rmse(source, _gather_patches(views.images, target_view, centre, patch_size))
    if search_radius > 0:  # the best of the (2 s + 1)^2 target patches around the reprojected pixel
        low = torch.tensor([[patch_size // 2] * 2], device=centre.device)
        high = torch.tensor([[views.width - 1 - patch_size // 2, views.height - 1 - patch_size // 2]],
                            device=centre.device)
        shifts = _patch_offsets(2 * search_radius + 1, centre.device)
        for shift in shifts[(shifts != 0).any(dim=1)]:  # the centre patch's error is `error` already
            shifted = torch.minimum(torch.maximum(centre + shift, low), high)
            error = torch.minimum(error, _patch_rmse(source, _gather_patches(views.images, target_view, shifted,
                                                                             patch_size)))
    valid = inside & target_inside
    if require_in_front:
        valid = valid & (z_target > 0)
    return error.masked_fill(~valid, math.inf), valid


def patch_reprojection_error(
    views: Views, rays: RayBatch, depth: torch.Tensor, patch_size: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """How well a depth explains the nearest train view: RMSE between the patch at the ray's pixel and the patch at
    the pixel its 3D point reprojects to.

    X = o + z d (z detached) is projected into view b = nearest[a] with b's own intrinsics and rounded to the nearest
    pixel; the k x k patch around uv in image a is compared with the k x k patch around that pixel in image b at the
    same integer offsets (the whole patch shifts by the centre's disparity). Source pixels are rounded as well, so
    continuous (e.g. keypoint) pixels are allowed.

    Args:
        views: the V train views (images in [0, 1], per-view cameras, `nearest`).
        rays: R rays of those views: `view` [R], pixel `uv` [R, 2], `rays.origins` / `rays.directions` [R, 3]
            (point = o + z d, see `simplenerf.geometry.rays`).
        depth: [R] camera z-depth of each ray's surface point.
        patch_size: k, odd.

    Returns:
        error [R] in the images' dtype, +inf where invalid; valid [R] bool: both patches lie inside their images
        (centres at least k // 2 px from every border) and X is in front of camera b (camera z > 0).
    """
    _check_patch_size(patch_size)
    source, source_inside = _source_patches(views.images, rays.view, rays.uv, patch_size)
    return _reprojection_error(views, rays, depth, source, source_inside, patch_size)


def ternary_mask(error_main: torch.Tensor, error_other: torch.Tensor, threshold: float) -> torch.Tensor:
    """Which of two depths is reliable (paper eq. 6).

    Every comparison is strict (<), as in the release (src/loss_functions/PointsAugmentationDepthLoss02.py,
    compute_loss_nerf), where the paper's equation has e_other <= e_main and <= e_tau:
    so a tie gives 0, and so does an error exactly at the threshold. Invalid rays carry e = inf and give 0.

    Args:
        error_main, error_other: [R] reprojection errors of the main and the other depth.
        threshold: e_tau; a depth whose error is not below it is never trusted.

    Returns:
        [R] in the errors' dtype with values +1 (other is reliable and better: train main toward it), -1 (main is
        reliable and better: train other toward it) and 0 (neither). Floating point so it multiplies losses directly.
    """
    one = torch.ones_like(error_main)
    plus = (error_other < error_main) & (error_other < threshold)
    minus = (error_main < error_other) & (error_main < threshold)
    return torch.where(plus, one, torch.where(minus, -one, torch.zeros_like(one)))


def mask_fractions(mask: torch.Tensor) -> dict[str, torch.Tensor]:
    """Fractions of rays at each mask value, for logging (0-dim tensors, no host sync).

    Args:
        mask: [R] ternary mask (`ternary_mask`), floating point.

    Returns:
        {"plus": fraction at +1, "minus": fraction at -1, "zero": fraction at 0}.
    """
    return {
        "plus": (mask == 1).to(mask.dtype).mean(),
        "minus": (mask == -1).to(mask.dtype).mean(),
        "zero": (mask == 0).to(mask.dtype).mean(),
    }


def limited_square(error: torch.Tensor, limit: float | None) -> torch.Tensor:
    """error^2, or with a `limit` the Huber form that equals it up to |error| = limit and grows linearly past it,
    limit (2 |error| - limit): the gradient of one ray is bounded by 2 limit. Not in the paper: a metric depth near
    the NDC far plane grows without bound, and one such ray can make a masked depth loss 1000 times its usual value
    for a step (docs/results.md, "Where the blur and the streaks come from", 14)."""
    if limit is None:
        return error.square()
    return 2.0 * F.huber_loss(error, torch.zeros_like(error), reduction="none", delta=limit)  # 0.5 e^2 below delta


def masked_depth_loss(
    z_main: torch.Tensor, z_other: torch.Tensor, mask: torch.Tensor | None, direction: Direction,
    limit: float | None = None,
) -> torch.Tensor:
    """The depth consistency losses L_ap, L_av and L_cfc (paper eqs. 3, 4, 7).

    The mean is over ALL rays, masked-out ones counting as zero (as in the authors' release), so the loss scale
    falls when fewer depths are reliable.

    Args:
        z_main: [R] depth of the main model (e.g. main coarse).
        z_other: [R] depth of the other model (augmented, or main fine).
        mask: [R] ternary mask, or None to trust every ray: plain mean((z_main - z_other)^2), gradient to both.
        direction: "bidirectional" (the paper): 1{m=+1} (z_main - sg(z_other))^2 + 1{m=-1} (sg(z_main) - z_other)^2;
            "one_way" (what the release effectively trains: compute_depth_mse of src/loss_functions/
            PointsAugmentationDepthLoss02.py and its siblings zeroes its inputs in place, so the m = -1 term is always
            0): only the m = +1 term.
        limit: None (the paper): squared errors; a depth difference: `limited_square`'s Huber form past it.

    Returns:
        [] scalar loss.
    """
    if direction not in ("bidirectional", "one_way"):
        raise ValueError(f"direction must be 'bidirectional' or 'one_way', got {direction!r}")
    if mask is None:
        return limited_square(z_main - z_other, limit).mean()
    zero = torch.zeros_like(z_main)
    # torch.where rather than a product, so that a non-finite depth of a masked-out ray cannot turn the loss into NaN.
    loss = torch.where(mask == 1, limited_square(z_main - z_other.detach(), limit), zero)
    if direction == "bidirectional":
        loss = loss + torch.where(mask == -1, limited_square(z_main.detach() - z_other, limit), zero)
    return loss.mean()


class ReprojectionErrors:
    """The patch reprojection errors (`patch_reprojection_error`) of depths of one batch of train rays, each computed
    once: in a training step the main coarse depth is judged by three pairs (L_ap, L_av, L_cfc), and its error, like
    the source patches and their texture, is shared by them."""

    def __init__(self, views: Views, rays: RayBatch) -> None:
        """
        Args:
            views: the train views. rays: R rays of them.
        """
        self.views, self.rays = views, rays
        self._sources: dict[int, tuple[torch.Tensor, torch.Tensor]] = {}
        self._errors: dict[tuple[str, int, bool, int], torch.Tensor] = {}
        self._textures: dict[int, torch.Tensor] = {}

    def _source(self, patch_size: int) -> tuple[torch.Tensor, torch.Tensor]:
        """The rays' own k x k patches [R, k * k, 3] and whether each fits in its image [R], gathered once."""
        if patch_size not in self._sources:
            self._sources[patch_size] = _source_patches(self.views.images, self.rays.view, self.rays.uv, patch_size)
        return self._sources[patch_size]

    def __call__(
        self, name: str, depth: torch.Tensor, patch_size: int, require_in_front: bool = True, search_radius: int = 0
    ) -> torch.Tensor:
        """[R] error of depth [R] (inf where invalid); `name` says which render the depth is (e.g. "coarse"): the same
        name with the same patch rule is computed once."""
        key = (name, patch_size, require_in_front, search_radius)
        if key not in self._errors:
            source, inside = self._source(patch_size)
            self._errors[key], _ = _reprojection_error(self.views, self.rays, depth, source, inside, patch_size,
                                                       require_in_front, search_radius)
        return self._errors[key]

    def texture(self, patch_size: int) -> torch.Tensor:
        """[R] `patch_texture` of the rays' own k x k patches (0 where the patch does not fit in the image), computed
        once."""
        if patch_size not in self._textures:
            source, inside = self._source(patch_size)
            self._textures[patch_size] = torch.where(inside, patch_texture(source), torch.zeros((), dtype=source.dtype))
        return self._textures[patch_size]


class ReliabilityMask(abc.ABC):
    """Decides, per ray, which of two depth estimates supervises the other (Sec. 4.2)."""

    @abc.abstractmethod
    def __call__(
        self, views: Views, rays: RayBatch, z_main: torch.Tensor, z_other: torch.Tensor
    ) -> torch.Tensor | None:
        """The ternary mask [R] (see `ternary_mask`) for depths z_main, z_other [R] of `rays` (of the train `views`),
        or None for "no mask": every ray is trusted and `masked_depth_loss` applies no stop-gradient."""

    def judge(
        self, errors: ReprojectionErrors, main: str, z_main: torch.Tensor, other: str, z_other: torch.Tensor
    ) -> torch.Tensor | None:
        """The mask in a training step, whose reprojection errors `errors` shares across its depth pairs; `main` and
        `other` name the renders of z_main and z_other. By default the mask of `__call__`."""
        return self(errors.views, errors.rays, z_main, z_other)


class PatchReprojectionMask(ReliabilityMask):
    """The paper's mask: the depth whose k x k patch reprojects better into the nearest train view, if good enough."""

    def __init__(
        self, patch_size: int = 5, error_threshold: float = 0.1, require_in_front: bool = True,
        require_both_valid: bool = False, min_texture: float = 0.0, search_radius: int = 0,
        max_pull_back: float | None = None,
    ) -> None:
        """
        Args:
            patch_size: side k of the square patch compared between views (odd).
            error_threshold: e_tau, the patch RMSE (images in [0, 1]) below which a depth can be trusted.
            require_in_front: a depth whose 3D point lies behind the nearest view's camera is never trusted. The
                release (`loss_functions/*DepthLoss02.py`, `utils/CommonUtils01.reproject`) has no such check: a
                point behind the camera projects through the pinhole mirrored and may be compared with an unrelated
                patch. False reproduces the release (used by `benchmarks/equivalence/check.py`).
            require_both_valid: judge a ray only where both depths' patches land in the nearest view (mask 0
                elsewhere). False (the paper, eq. 6, and the release): a depth that leaves the view has error inf, so
                the other depth wins whenever its own error is below e_tau; at the edge of what the nearest view sees,
                a wrong depth that lands in a plain region of it is then trusted over a right one that leaves it
                (docs/results.md, "Where the blur and the streaks come from", 16).
            min_texture: judge a ray only where its own k x k patch has at least this `patch_texture` (images in
                [0, 1]; mask 0 elsewhere). 0 (the paper and the release): every ray is judged, also in plain regions,
                where any depth that lands on a plain patch passes e_tau and the two depths win by chance (16).
            search_radius: s; a depth's error is the least over the (2 s + 1)^2 patches of the nearest view centred
                within s px (each axis) of the pixel it reprojects to, rather than that one patch. 0 (the paper and
                the release): one patch, so the comparison assumes the views register to a pixel. At LLFF images_4
                they do not: a fern SfM point of one train view, projected at its SfM depth into the other, lands
                1.35 px (median) from where that view observed it, 3.8 px on the near leaves, and there the right
                depth's 5 x 5 patch misses e_tau and loses to a farther one (docs/results.md, "Where the blur and
                the streaks come from", 18).
            max_pull_back: f; never train a depth toward one more than f (a fraction of itself) farther from the
                camera: where the winner's depth exceeds the loser's by more than f times the loser's, the mask is 0.
                None (the paper and the release): the better patch wins in either direction, so a thin near
                structure whose patch a farther depth also explains (fern's leaves in front of the plain wall) can
                be pulled back to what is behind it (docs/results.md, "Where the blur and the streaks come from",
                19 and 33).
        """
        _check_patch_size(patch_size)
        if not error_threshold > 0:
            raise ValueError(f"error_threshold must be positive, got {error_threshold}")
        self.patch_size, self.error_threshold = patch_size, error_threshold
        if not min_texture >= 0:
            raise ValueError(f"min_texture must be >= 0, got {min_texture}")
        self.require_in_front, self.require_both_valid = require_in_front, require_both_valid
        self.min_texture = min_texture
        if search_radius < 0:
            raise ValueError(f"search_radius must be >= 0, got {search_radius}")
        self.search_radius = search_radius
        if max_pull_back is not None and not max_pull_back >= 0:
            raise ValueError(f"max_pull_back must be >= 0 or None, got {max_pull_back}")
        self.max_pull_back = max_pull_back

    def __call__(self, views: Views, rays: RayBatch, z_main: torch.Tensor, z_other: torch.Tensor) -> torch.Tensor:
        return self.judge(ReprojectionErrors(views, rays), "main", z_main, "other", z_other)

    def judge(
        self, errors: ReprojectionErrors, main: str, z_main: torch.Tensor, other: str, z_other: torch.Tensor
    ) -> torch.Tensor:
        e_main = errors(main, z_main, self.patch_size, self.require_in_front, self.search_radius)
        e_other = errors(other, z_other, self.patch_size, self.require_in_front, self.search_radius)
        mask = ternary_mask(e_main, e_other, self.error_threshold)
        if self.require_both_valid:
            mask = torch.where(torch.isfinite(e_main) & torch.isfinite(e_other), mask, 0.0)
        if self.min_texture > 0:
            mask = torch.where(errors.texture(self.patch_size) >= self.min_texture, mask, 0.0)
        if self.max_pull_back is not None:  # the winner: z_other where +1 (it trains z_main), z_main where -1
            winner, loser = torch.where(mask == 1, z_other, z_main), torch.where(mask == 1, z_main, z_other)
            mask = torch.where(winner > (1 + self.max_pull_back) * loser, 0.0, mask)
        return mask


class TrustAll(ReliabilityMask):
    """No mask: every depth is trusted and both models pull on each other (the paper's "w/o reliable depth")."""

    def __call__(self, views: Views, rays: RayBatch, z_main: torch.Tensor, z_other: torch.Tensor) -> None:
        return None

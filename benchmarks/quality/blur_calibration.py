"""What LPIPS and PSNR blur and misplacement alone cost, on a scene's held-out photos (docs/results.md "Where the blur
and the streaks come from"): each test photo against degraded copies of itself, which a renderer could at best match.

- `downN_up`: the photo shrunk N times (area) and enlarged back (bilinear): the detail of a render with one node or
  sample per N pixels;
- `gaussS`: a Gaussian blur of S pixels; `rowblur9`: a 9-pixel box blur along rows (a horizontal streak);
- `shiftN`: the photo moved N pixels sideways (geometry misplaced by N pixels, detail kept);
- `nearest_train`: the nearest training photo as it is (no warp at all).

    python -m benchmarks.quality.blur_calibration ../shared/data/nerf_llff_data/fern --factor 4 [--views 2]

Prints one JSON line: per degradation, mean PSNR and LPIPS over the test frames (the paper's LLFF split), and the copy's
streak index (benchmarks.quality.streak_index: the whole frame, its 4 vertical strips, and against the photo blurred as
much; docs/results.md, "Where the blur and the streaks come from", 35): what blur alone does to the index.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np
import torch

from benchmarks.quality.streak_index import axis_ratio, matched_blur, strip_ratios
from simplenerf.data.llff import list_images, llff_split, read_image
from simplenerf.metrics.lpips import LPIPS
from simplenerf.metrics.scores import lpips, psnr


def degraded(photo: np.ndarray) -> dict[str, np.ndarray]:
    """The degraded copies of an [H, W, 3] uint8 photo, by name."""
    height, width = photo.shape[:2]
    out = {}
    for n in (2, 4, 8):
        small = cv2.resize(photo, (width // n, height // n), interpolation=cv2.INTER_AREA)
        out[f"down{n}_up"] = cv2.resize(small, (width, height), interpolation=cv2.INTER_LINEAR)
    for sigma in (1, 2, 4):
        out[f"gauss{sigma}"] = cv2.GaussianBlur(photo, (0, 0), sigma)
    out["rowblur9"] = cv2.blur(photo, (9, 1))
    for n in (2, 5, 10):
        shift = np.float32([[1, 0, n], [0, 1, 0]])
        out[f"shift{n}"] = cv2.warpAffine(photo, shift, (width, height), borderMode=cv2.BORDER_REFLECT)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scene", type=Path, help="an LLFF scene folder (images_<factor>/)")
    parser.add_argument("--factor", type=int, default=4)
    parser.add_argument("--views", type=int, default=2, help="training views of the split (for nearest_train)")
    args = parser.parse_args()
    paths = list_images(args.scene / f"images_{args.factor}")
    split = llff_split(len(paths), args.views)
    photos = [read_image(p) for p in paths]
    net = LPIPS.from_weights()

    def tensor(image: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(image.astype(np.float32) / 255.0)[None]

    scores: dict[str, dict[str, list]] = {}
    for i in split.test:
        target = tensor(photos[i])
        photo_ratio, photo_strips = axis_ratio(photos[i]), strip_ratios(photos[i], 4)
        copies = degraded(photos[i])
        copies["nearest_train"] = photos[min(split.train, key=lambda j: abs(j - i))]
        for name, image in copies.items():
            pred = tensor(image)
            soft = matched_blur(photos[i], image)[1]
            for key, value in (("psnr", psnr(pred, target).item()), ("lpips", lpips(pred, target, net).item()),
                               ("streak", axis_ratio(image) / photo_ratio),
                               ("streak_strips", strip_ratios(image, 4) / photo_strips),
                               ("streak_matched", axis_ratio(image) / axis_ratio(soft))):
                scores.setdefault(name, {}).setdefault(key, []).append(value)
    digits = {"psnr": 2}
    print(json.dumps({"scene": str(args.scene), "factor": args.factor, "test_frames": split.test,
                      "scores": {name: {key: np.round(np.mean(values, axis=0), digits.get(key, 3)).tolist()
                                        for key, values in by_key.items()}
                                 for name, by_key in scores.items()}}))


if __name__ == "__main__":
    main()

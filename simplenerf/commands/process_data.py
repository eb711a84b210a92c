"""Photos of one scene -> a scene folder in the LLFF layout (images/, images_N/, poses_bounds.npy) for `simplenerf
fit`, with a report (sfm_report.json) and a top view (sfm_top_view.png) of the cameras and points. Structure from
motion with pycolmap on the CPU (simplenerf.sfm.photos), e.g.

    simplenerf process-data --images photos/ --output data/my_scene
    simplenerf fit --config configs/llff.yaml --data.init_args.scene_dir data/my_scene
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from simplenerf.commands import CommandParser
from simplenerf.sfm.mapping import CAMERA_MODELS
from simplenerf.sfm.photos import process_photos


def build_parser() -> CommandParser:
    parser = CommandParser("process-data", __doc__)
    parser.add_argument("--images", required=True, type=Path, help="folder of photos (jpg, png, tif, bmp, webp)")
    parser.add_argument("--output", required=True, type=Path, help="scene folder to create, e.g. data/my_scene")
    parser.add_argument("--factors", type=int, nargs="*", default=[4, 8],
                        help="write images_N/ at 1/N size for each N (default: 4 8; images/ is always written)")
    parser.add_argument("--camera", choices=["shared", "per-photo"], default="shared",
                        help="one camera for all photos (same camera and zoom; default) or one per photo (several "
                        "cameras or zooms; each focal length is then estimated on its own, which needs many photos)")
    parser.add_argument("--camera_model", choices=CAMERA_MODELS, default="SIMPLE_RADIAL",
                        help="COLMAP camera model (default SIMPLE_RADIAL: focal, centre, one radial distortion term)")
    parser.add_argument("--max_size", type=int, help="downscale photos so the longer side is at most this first")
    parser.add_argument("--sift_max_size", type=int, default=3200,
                        help="SIFT looks at photos downscaled to at most this longer side (default 3200)")
    parser.add_argument("--max_features", type=int, default=8192, help="SIFT keypoints per photo (default 8192)")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing output folder")
    parser.add_argument("--seed", type=int, default=0, help="seed of COLMAP's random choices")
    parser.add_argument("--threads", type=int, default=-1, help="CPU threads for COLMAP (default: all)")
    parser.add_argument("--verbose", action="store_true", help="show COLMAP's own log")
    return parser


def main(argv: Sequence[str]) -> None:
    args = build_parser().parse_args(argv)
    process_photos(
        args.images, args.output, factors=args.factors, shared_camera=args.camera == "shared",
        camera_model=args.camera_model, max_size=args.max_size, sift_max_size=args.sift_max_size,
        max_num_features=args.max_features, overwrite=args.overwrite, seed=args.seed, num_threads=args.threads,
        verbose=args.verbose,
    )

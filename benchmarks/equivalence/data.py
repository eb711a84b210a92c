"""Issue 20, point 1: the data this codebase trains on equals the data the release trains on.

For one scene and view count, the release's own loader (`data_loaders/NerfLlffDataLoader01.py` or
`RealEstateDataLoader01.py`) and preprocessor (`data_preprocessors/DataPreprocessor01.py`, modes train / validation
and its test-time `create_test_data`) run on the release's layout of the scene (`layouts.py`), configured by the
release's own published config (`NerfLlffTrainerTester01.py` / `RealEstateTrainerTester01.py`, demo1a / 1b / 1c for
2 / 3 / 4 views, captured at run time); ours runs through `simplenerf.run.cli.make_cli` with configs/llff.yaml or
configs/realestate.yaml. Rows compare:
1. train / validation / test frame numbers (exact);
2. intrinsics, c2w after recentring and scaling, near / far, bounds and scale (and the authors' committed
   `runs/training/*/ModelConfigs.json`, an anchor that the layout is the authors' own);
3. world and NDC rays and colours of `pixels_per_view` seeded pixels of every train view, the validation view and a
   test view;
4. sparse depth: synthetic 3D points (in file units, seen by at least two train views) are written to the release as
   its CSVs (x, y, depth, reprojection_error, weight per frame) and given to ours as the SfM result our pipeline
   would compute for them (each point placed in OUR scene from its generating view, its depth the z-depth in each
   observing view of OUR cameras: `known_poses.collect`'s definition); then the per-ray targets of the release's
   sparse-depth batch (`get_next_batch`: `sparse_depth_values`) and of ours (`RandomRays.sparse_batch`:
   `SparseDepthBatch.depth`, `weight`) for the same points, and their rays.

Pose convention: the release stores world-to-camera 4x4 matrices in OpenCV axes (CameraExtrinsics.csv); after
`preprocess_poses` (scale the translation by sc, `recenter_poses` = average_pose @ inv(w2c), which turns them into
camera-to-world, then `convert_pose_to_standard_coordinates`: R -> P R P, t -> P t with P = diag(1, -1, -1)) its
`poses[:, :3, :4]` are camera-to-world in OpenGL axes (right, up, back) in the average camera's OpenGL frame, the
same convention as our `Views.c2w`: the mapping is the identity, ours c2w == release poses[:, :3, :4].
Pixel convention: both put the ray of pixel index (u, v) through the continuous coordinate (u, v) with the principal
point (W/2, H/2) (release `get_rays`: K^-1 [x, y, 1] with y, z negated; ours `pixel_rays`), so a sparse-depth
keypoint x of the release's CSV is our uv = x.

Run it (prints the markdown table of every case):
    python -m benchmarks.equivalence.data --release-src /path/to/SimpleNeRF/src --work-dir /tmp/eqdata
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys
import time
from pathlib import Path

import numpy as np
import torch

from benchmarks.equivalence.layouts import (
    ReleaseRepo,
    build_llff_layout,
    build_realestate_layout,
    write_sparse_depth_csvs,
)
from benchmarks.equivalence.rays import ours_rays, pixels, ray_rows, release_rays
from benchmarks.equivalence.release import release_config, run_release
from benchmarks.equivalence.report import Report, Row, compare, exact, flag
from benchmarks.equivalence.sparse_depth import (
    csv_tables,
    our_sparse_depth,
    patched_sparse_depth,
    sparse_rows,
    synthetic_observations,
)

REPO_ROOT = Path(__file__).resolve().parents[2]
DEFAULT_RELEASE_GIT = Path("/work/.mirror/NagabhushanSN95+SimpleNeRF/repo")
COMMITTED_RUNS = {("llff", 2): "train1011", ("llff", 3): "train1021", ("llff", 4): "train1031",
                  ("realestate", 2): "train0011", ("realestate", 3): "train0021", ("realestate", 4): "train0031"}


def our_datamodule(kind: str, scene_dir: Path, n_views: int, factor: int, work_dir: Path):
    """Our data module through the real CLI and config (configs/llff.yaml or configs/realestate.yaml)."""
    from simplenerf.run.cli import make_cli

    config = REPO_ROOT / ("configs/llff.yaml" if kind == "llff" else "configs/realestate.yaml")
    args = ["--config", str(config), "--data.init_args.scene_dir", str(scene_dir),
            "--data.init_args.n_views", str(n_views), "--data.init_args.sparse_depth_cache",
            str(work_dir / "our_sparse_depth_cache"), "--trainer.logger", "false",
            "--trainer.default_root_dir", str(work_dir / "our_runs")]
    if kind == "llff":
        args += ["--data.init_args.factor", str(factor)]
    with contextlib.redirect_stdout(sys.stderr):
        cli = make_cli(args, run=False)
    return cli


def data_rows(release_src: Path, work_dir: Path, scene_dir: Path, kind: str, n_views: int, factor: int = 4,
              pixels_per_view: int = 2000, points_per_view: int = 300, seed: int = 0,
              release_git: Path | None = None) -> list[Row]:
    """Every data row for one scene and view count (see the module docstring).

    kind "llff" (scene_dir: an LLFF scene, images_{factor}) or "realestate" (scene_dir: a RealEstate-10K video
    folder <id>/{<id>.txt, frames/}); work_dir: scratch outside the repository (the release's layout, reused).
    """
    torch.set_default_dtype(torch.float32)
    repo = ReleaseRepo(Path(release_src), release_git)
    work_dir, scene_dir = Path(work_dir), Path(scene_dir)
    layout_root = work_dir / "release_layout"
    name = scene_dir.name if kind == "llff" else f"RE10K {scene_dir.name[:6]}"
    group = f"data {name} {n_views}v" + (f" images_{factor}" if kind == "llff" else "")
    rows: list[Row] = []

    configs = release_config(repo, kind, n_views)
    if kind == "llff":
        layout = build_llff_layout(repo, layout_root, scene_dir, factor)
        configs["data_loader"]["resolution_suffix"] = layout["suffix"]
        scene_id = scene_dir.name
        depth_dir = (layout["db"] / "all/estimated_depths" / configs["data_loader"]["sparse_depth"]["dirname"]
                     / scene_id / f"estimated_depths{layout['suffix']}")
        bounds_file = layout["bounds"]
    else:
        layout = build_realestate_layout(repo, layout_root, scene_dir)
        scene_id = f"{layout['scene_num']:05}"
        depth_dir = (layout["db"] / "test/estimated_depths" / configs["data_loader"]["sparse_depth"]["dirname"]
                     / scene_id / "estimated_depths")
        bounds_file = np.tile([1.0, 100.0], (len(layout["w2c"]), 1))  # RealEstateDataLoader01: bounds [1, 100]
    h, w = layout["height"], layout["width"]

    rng = np.random.default_rng(seed)
    synthetic = {}

    def make_csvs(train_frames):
        per_view = synthetic_observations(layout["w2c"][train_frames], layout["intrinsics"][train_frames],
                                          bounds_file[train_frames], h, w, points_per_view, rng)
        write_sparse_depth_csvs(depth_dir, dict(zip(train_frames.tolist(), csv_tables(per_view), strict=True)))
        synthetic["per_view"], synthetic["frames"] = per_view, train_frames

    with contextlib.redirect_stdout(sys.stderr):
        release = run_release(repo, configs, layout["db"], scene_id, make_csvs)
    train_pre, val_pre, mc = release["train"], release["val"], release["model_configs"]
    rel_train = train_pre.preprocessed_data_dict["frame_nums"]
    rel_val = val_pre.preprocessed_data_dict["frame_nums"]
    rel_test = release["test_frames"]

    cli = our_datamodule(kind, scene_dir, n_views, factor, work_dir)
    dm = cli.datamodule

    def provide(key, images, intrinsics, c2w):
        sparse, synthetic["our_uv"] = our_sparse_depth(synthetic["per_view"], intrinsics, c2w, dm.scene.scale)
        return sparse

    with patched_sparse_depth(provide), contextlib.redirect_stdout(sys.stderr):
        dm.setup("fit")
    scene = dm.scene
    split = scene.split

    # 1. frame numbers (ours index the sorted frames, = the release's frame numbers by its layout)
    rows.append(exact(group, "train frame numbers", split.train, rel_train))
    rows.append(exact(group, "test frame numbers", split.test, rel_test))
    if kind == "realestate":  # the release's frame n is the n-th camera line from the scene's start timestamp
        rows.append(exact(group, "clip's first camera-file line", dm.clip_start, layout["first_line"],
                          note="release: DataExtractor01 demo1's start timestamp; ours: data.clip_start"))
    if list(split.val) == list(rel_val):
        rows.append(exact(group, "validation frame numbers", split.val, rel_val))
    else:
        rows.append(flag(group, "validation frame numbers", True,
                         f"deliberate difference: ours {list(split.val)}, release {rel_val.tolist()} (ours: the "
                         "middle test frame, as the release's LLFF split TrainTestCreator01_UniformSparseSampling.py "
                         "chooses it; validation renders pictures only, no training input; the "
                         "validation rows below use the release's frames)"))

    # 2. cameras
    views = scene.views
    rel_poses = train_pre.preprocessed_data_dict["nerf_data"]["poses"]
    rel_k = train_pre.preprocessed_data_dict["nerf_data"]["intrinsics"]
    rows.append(compare(group, "train intrinsics", views.intrinsics[split.train], rel_k, 1e-6, 1e-6))
    rows.append(compare(group, "train c2w (release poses[:, :3, :4])", views.c2w[split.train], rel_poses[:, :3, :4],
                        1e-5, 1e-6))
    val_poses = val_pre.preprocessed_data_dict["nerf_data"]["poses"]
    rows.append(compare(group, "validation c2w", views.c2w[rel_val.tolist()], val_poses[:, :3, :4], 1e-5, 1e-6))
    test_w2c = layout["w2c"][rel_test]
    test_poses = train_pre.preprocess_poses({"poses": test_w2c.copy(), "translation_scale": mc["translation_scale"],
                                             "average_pose": np.array(mc["average_pose"])}, train_mode=False)["poses"]
    rows.append(compare(group, "test c2w (create_test_data's preprocess_poses)", views.c2w[rel_test.tolist()],
                        test_poses[:, :3, :4], 1e-5, 1e-6))
    rows.append(compare(group, "test intrinsics", views.intrinsics[rel_test.tolist()],
                        layout["intrinsics"][rel_test], 1e-6, 1e-6))
    rows.append(compare(group, "scale (translation_scale)", scene.scale, mc["translation_scale"], 1e-7, 0.0))
    train_bounds = scene.bounds[split.train]
    rows.append(compare(group, "bounds [min, max] of train views (scaled)",
                        [train_bounds.min(), train_bounds.max()], mc["bounds"], 1e-6, 0.0))
    rows.append(compare(group, "near (NDC near plane)", [dm.near, cli.model.nerf.near], [mc["near"]] * 2, 1e-6, 0.0))
    rows.append(compare(group, "far", train_bounds.max(), mc["far"], 1e-6, 0.0,
                        note="ours: not used (NDC samples t in [0, 1])"))
    rows.append(exact(group, "NDC sample range [near_ndc, far_ndc]", [0.0, 1.0], [mc["near_ndc"], mc["far_ndc"]],
                      note="ours: samplers.stratified_samples linspace(0, 1)"))
    rows.extend(committed_rows(repo, group, kind, n_views, scene_id, mc, h, w))

    # 3. rays at seeded pixels of every train view, the validation view and one test view
    train_views = dm.train_views
    pix = pixels(rng, len(split.train), h, w, pixels_per_view)
    ours, ours_rgb = ours_rays(train_views, pix, dm.near)
    rel = release_rays(train_pre.preprocessed_data_dict["nerf_data"], pix, h, w)
    rows.extend(ray_rows(group, f"train rays ({len(split.train)} x {pixels_per_view} px)", ours, rel, ours_rgb))
    # Our real training batch (RandomRays, seeded): its rays and colours at its pixels vs the release's cache there.
    random = next(iter(dm.train_dataloader().dataset)).random
    pix = np.stack([random.view.numpy(), random.uv[:, 0].numpy(), random.uv[:, 1].numpy()], -1)
    rel = release_rays(train_pre.preprocessed_data_dict["nerf_data"], pix, h, w)
    rows.extend(ray_rows(group, f"our first training batch ({len(random)} random rays)", random.rays, rel,
                         random.rgb, note="RandomRays: pixels by our seeded shuffle, looked up in the release's cache"))
    val_views = views.subset(rel_val.tolist())
    pix = pixels(rng, len(rel_val), h, w, pixels_per_view)
    ours, ours_rgb = ours_rays(val_views, pix, dm.near)
    rel = release_rays(val_pre.preprocessed_data_dict["nerf_data"], pix, h, w)
    what = f"validation rays ({len(rel_val)} x {pixels_per_view} px)"
    val_near = val_pre.preprocessed_data_dict["nerf_data"]["near"]
    if abs(val_near - mc["near"]) <= 1e-6 * mc["near"]:
        rows.extend(ray_rows(group, what, ours, rel, ours_rgb))
    else:
        # The release's validation preprocessor puts its NDC near plane at 0.75 x the VALIDATION frames' smallest
        # scaled bound (DataPreprocessor01.preprocess_raw_nerf_data in mode validation: near = bds[0] * bd_factor
        # of the validation bounds), not at the training near (1) that its model and create_test_data use.
        note = (f"release bug, validation only: its NDC near is {val_near:.6f} (0.75 x the validation frames' min "
                f"bound), not the training near {mc['near']:g}; ours uses {dm.near:g}; here ours switched to "
                f"near {val_near:.6f}")
        switched, _ = ours_rays(val_views, pix, val_near)
        rows.extend(ray_rows(group, what, switched, rel, ours_rgb, note=note))
        rows.append(compare(group, f"{what}: NDC ray directions at ours' near 1 (not a failure)", ours.ndc_directions,
                            rel["rays_d_ndc"], np.inf, 0.0, note="the size of the release's validation-near bug"))
    test_frame = int(rel_test[len(rel_test) // 2])
    batch = train_pre.create_test_data(layout["w2c"][test_frame], intrinsic=layout["intrinsics"][test_frame])
    pix = pixels(rng, 1, h, w, pixels_per_view)
    flat = torch.from_numpy(pix[:, 2] * w + pix[:, 1]).long()
    rel = {k: batch[k].cpu()[flat] for k in ("rays_o", "rays_d", "rays_o_ndc", "rays_d_ndc")}
    from simplenerf.data.datasets import Frames

    frame = Frames(views, dm.near, [test_frame])[0]
    ours = frame.rays[flat]
    rows.extend(ray_rows(group, f"test frame {test_frame} rays ({pixels_per_view} px)", ours, rel))

    # 4. sparse depth
    rows.extend(sparse_rows(group, dm, train_pre, synthetic, h, w))
    return rows


def committed_rows(repo: ReleaseRepo, group: str, kind: str, n_views: int, scene_id: str, mc: dict, h: int,
                   w: int) -> list[Row]:
    """The release run on this layout vs the authors' own run (runs/training/<run>/<scene>/ModelConfigs.json)."""
    relpath = f"runs/training/{COMMITTED_RUNS[(kind, n_views)]}/{scene_id}/ModelConfigs.json"
    try:
        committed = json.loads(repo.read(relpath))
    except (FileNotFoundError, OSError, Exception):  # noqa: BLE001 - a scene the authors did not run
        return []
    g = f"{group} vs authors' {relpath.split('/')[2]}"
    rows = [
        exact(g, "train frame numbers", mc["train_frame_nums"], committed["train_frame_nums"]),
        compare(g, "translation_scale", mc["translation_scale"], committed["translation_scale"], 1e-6, 0.0),
        compare(g, "average_pose (w2c, OpenCV)", mc["average_pose"], committed["average_pose"], 1e-5, 1e-6),
        compare(g, "bounds, near, far", [*mc["bounds"], mc["near"], mc["far"]],
                [*committed["bounds"], committed["near"], committed["far"]], 1e-6, 0.0),
    ]
    ch, cw = committed["resolution"]
    if kind == "llff":
        ratio = w / cw
        note = "" if ratio == 1 else f"authors' at {cw}x{ch} scaled by {ratio:g} (this scene is at {w}x{h})"
        k = np.array(committed["intrinsic"])
        k[:2] *= ratio
        rows.append(compare(g, "intrinsic", mc["intrinsic"], k, 1e-6, 0.0, note=note))
    else:
        rows.append(flag(g, "intrinsic", True, f"not compared: the authors' frames are {cw}x{ch}, this project's copy "
                                              f"is the {w}x{h} centre crop with intrinsics adjusted"))
    return rows


# ----------------------------------------------------------------------------------------------------------------
# The command


NOTES = """Notes
- Pose convention: the release's CameraExtrinsics.csv holds world-to-camera 4x4 in OpenCV axes; after its
  preprocess_poses (translation x sc, recenter_poses = average_pose @ inv(w2c), convert_pose_to_standard_coordinates
  R -> P R P, t -> P t, P = diag(1, -1, -1)) poses[:, :3, :4] is camera-to-world in OpenGL axes in the average camera's
  frame: identical to our Views.c2w (no axis change). Pixels: both cast pixel index (u, v) through (u, v), principal
  point (W/2, H/2).
- LLFF cameras come from poses_bounds.npy (the release read COLMAP's sparse/0, absent here); the rows against the
  authors' committed runs/training/*/ModelConfigs.json show the same scale, average pose, bounds and intrinsics.
- horns is in ../shared at images_8 only (504x378): its cases run at images_8 (the release's _down8 layout); the paper
  uses images_4. RealEstate-10K: this project's copy is a 256x256 centre crop with intrinsics adjusted in the camera
  file (the paper: 1024x576); the layout is made by the release's own DataExtractor01 matrices from it, so the
  pipeline is compared on the crop.
- Sparse depth: synthetic 3D points (seeded), seen by >= 2 train views, one per rounded pixel; the release reads them
  from its CSVs, ours gets them in place of its SfM (sparse_depth.load_or_compute_sparse_depth patched at run time).
  Each codebase's own SfM (COLMAP CLI vs pycolmap; the release gives COLMAP cx = W/2 with pixel centres at +0.5,
  ours corrects the half pixel, `sfm.colmap`) is not compared here.
- Deliberate differences (listed in the rows): sparse-depth rays through the keypoint (ours) vs the nearest pixel
  (release); RealEstate-10K validation frames (ours the middle test frame; release 3 frames); the release's validation
  NDC near plane (a release bug: 0.75 x the validation frames' min bound instead of the training near 1)."""


def parse_case(text: str) -> dict:
    """`kind:scene_dir:n_views[:factor]`, e.g. llff:/data/nerf_llff_data/flower:2:4."""
    parts = text.split(":")
    kind, scene_dir, n_views = parts[0], Path(parts[1]), int(parts[2])
    factor = int(parts[3]) if len(parts) > 3 else (4 if kind == "llff" else 1)
    return {"kind": kind, "scene_dir": scene_dir, "n_views": n_views, "factor": factor}


def cases(data_root: Path) -> list[dict]:
    """The cases of issue 20: LLFF fern 2/3/4 views at images_4 (the paper's resolution), horns 2/3/4 at images_8
    (the only resolution of horns in ../shared), and the RealEstate-10K clip with 2 views."""
    llff = data_root / "nerf_llff_data"
    out = [{"kind": "llff", "scene_dir": llff / "fern", "n_views": n, "factor": 4} for n in (2, 3, 4)]
    out += [{"kind": "llff", "scene_dir": llff / "horns", "n_views": n, "factor": 8} for n in (2, 3, 4)]
    out += [{"kind": "realestate", "scene_dir": data_root / "realestate10k/000c3ab189999a83", "n_views": 2,
             "factor": 1}]
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--release-src", type=Path, required=True, help="the release's src/ folder")
    parser.add_argument("--release-git", type=Path, default=DEFAULT_RELEASE_GIT if DEFAULT_RELEASE_GIT.is_dir()
                        else None, help="the release's git directory, to read data/ and runs/ where --release-src's "
                                        "parent has none")
    parser.add_argument("--work-dir", type=Path, required=True, help="scratch folder outside the repository")
    parser.add_argument("--data-root", type=Path, default=REPO_ROOT.parent / "shared/data")
    parser.add_argument("--pixels-per-view", type=int, default=2000)
    parser.add_argument("--points-per-view", type=int, default=300)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--only", default=None, help="run the cases whose label contains this text, e.g. 'fern 2v'")
    parser.add_argument("--case", action="append", default=None, type=parse_case,
                        help="instead of the default cases: kind:scene_dir:n_views[:factor] (repeatable), e.g. "
                             "llff:/data/nerf_llff_data/flower:2:4 or realestate:/data/realestate10k/<id>:2")
    args = parser.parse_args(argv)
    os.environ.setdefault("CUDA_VISIBLE_DEVICES", "")
    report = Report()
    start = time.perf_counter()
    for case in args.case or cases(args.data_root):
        label = f"{case['scene_dir'].name} {case['n_views']}v"
        if args.only and args.only not in label:
            continue
        t0 = time.perf_counter()
        report.add(*data_rows(args.release_src.resolve(), args.work_dir.resolve(), case["scene_dir"].resolve(),
                              case["kind"], case["n_views"], case["factor"], args.pixels_per_view,
                              args.points_per_view, args.seed, args.release_git))
        print(f"{label}: {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
    print(report.markdown())
    print(f"\n{time.perf_counter() - start:.0f} s; release {args.release_src}; data {args.data_root}\n")
    print(NOTES)
    return 0 if report.passed else 1


if __name__ == "__main__":
    sys.exit(main())

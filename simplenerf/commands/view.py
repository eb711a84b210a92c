"""`simplenerf view RUN`: opens the web viewer of a trained run and prints its URL, e.g.

    simplenerf view runs/grid_demo
    simplenerf view runs/llff/checkpoints/step050000.ckpt --port 8081 --data.init_args.scene_dir ...

RUN is a run folder (its config.yaml and newest checkpoint: last.ckpt, else the newest *.ckpt) or a checkpoint file
(with its run's config.yaml two folders up, or --config). The CLI's options (`simplenerf fit`'s) are overrides of
the config. Exports go to `<run>/viewer/` unless --out. Bad input (no checkpoint, a port in use, a checkpoint that
does not fit its config) ends with one line.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch

from simplenerf.commands import CommandParser, split_overrides
from simplenerf.errors import DataError, RunFolderError
from simplenerf.run.checks import checkpoints_newest_first
from simplenerf.run.cli import load_for_tool
from simplenerf.run.console import HeldLogs
from simplenerf.viewer.server import Viewer, check_port


def port_number(text: str) -> int:
    """argparse's type of --port: an integer 0-65535."""
    try:
        port = int(text)
    except ValueError:
        port = -1
    if not 0 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"expected a port number 0-65535 (0: any free one), got {text}")
    return port


def build_parser() -> CommandParser:
    parser = CommandParser("view", __doc__)
    parser.add_argument("run", help="a run folder (trainer.default_root_dir of a fit) or a checkpoint file")
    parser.add_argument("--config", action="append", help="config file(s) of the run (default: <run>/config.yaml)")
    parser.add_argument("--host", default="127.0.0.1", help="address to listen on (0.0.0.0: every interface)")
    parser.add_argument("--port", type=port_number, default=8080, help="port, 0-65535 (0: any free one)")
    parser.add_argument("--resolution", type=int, help="larger side of the finest render (default: the photos')")
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu", help="torch device")
    parser.add_argument("--out", help="folder of screenshots and camera paths (default: <run>/viewer)")
    return parser


def resolve_run(run: Path, configs: list[str] | None) -> tuple[list[str], Path, Path]:
    """(config files, checkpoint, run folder) of RUN, a run folder or a checkpoint file."""
    if run.is_dir():
        found = checkpoints_newest_first(run / "checkpoints")
        scene_files = [name for name in ("poses_bounds.npy", "images", "frames") if (run / name).exists()]
        if not found and scene_files and not (run / "config.yaml").exists():
            raise DataError(f"{run} is a scene folder ({', '.join(scene_files)}), not a run: view shows a trained "
                            f"run; train one on it first (`simplenerf fit --config ... --data.init_args.scene_dir "
                            f"{run}`), then view its run folder")
        if not found:
            raise RunFolderError(f"run folder {run} has no checkpoint ({run / 'checkpoints'}/*.ckpt): train it first "
                                 f"(`simplenerf fit ...`), or give a checkpoint file")
        folder, checkpoint = run, found[0]
    elif run.is_file():
        folder, checkpoint = run.parent.parent, run
    else:
        raise DataError(f"{run} is neither a run folder nor a checkpoint file")
    if not configs:
        if not (folder / "config.yaml").is_file():
            raise RunFolderError(f"{folder / 'config.yaml'} does not exist: give the run's config with --config")
        configs = [str(folder / "config.yaml")]
    return configs, checkpoint, folder


def open_viewer(argv: list[str]) -> Viewer:
    """The viewer of the run `argv` names (the command's arguments), started."""
    own, overrides = split_overrides(argv)
    args = build_parser().parse_args(own)
    configs, checkpoint, folder = resolve_run(Path(args.run), args.config)
    check_port(args.host, args.port)  # before the model loads: a taken port says so at once
    held = HeldLogs()  # Lightning's lines (devices, seed) are not the viewer's: a bad checkpoint's error stands alone
    try:
        cli = load_for_tool(configs, overrides, stage="test", ckpt=str(checkpoint), device=args.device)
    finally:
        held.release(emit=False)
    model, data = cli.model, cli.datamodule
    if model.needs_masks:  # what the CLI hands a fit; `reliability_maps` reads it
        model.set_train_views(data.train_views.to(args.device))
    sparse = data.load_sparse_depth() if data.sparse_rays_per_batch else None  # cached by the fit
    out = Path(args.out) if args.out else folder / "viewer"
    print(f"viewer: {checkpoint}", flush=True)
    return Viewer(model, data.scene, data.near, out, sparse, args.host, args.port, args.resolution)


def main(argv: list[str]) -> None:
    viewer = open_viewer(argv)
    print(f"viewer: open {viewer.url} in a browser (Ctrl-C stops it)", flush=True)
    try:
        while True:
            time.sleep(1.0)
    finally:
        viewer.close()

"""Times the AUTHORS' RELEASE rendering a full test view (github NagabhushanSN95/SimpleNeRF at c429746); ONE JSON line.

Run it with the release's Python environment, not ours (see benchmarks/README.md, "The release"). It imports the
release's modules from an extracted copy, as ../shared/tools/official_timing/driver.py does, and changes nothing in
them: it reads the train config and model config that a driver.py run wrote (`<run_root>/runs/training/train<N>/`;
rendering does not depend on the variant's ray counts, only on its networks and `chunk` / `netchunk`), builds the
release's `Tester01.NerfTester` and times `NerfTester.predict_frame` (rays in numpy, the model's chunked forward
under no_grad, post-processing to an 8-bit image), the call the release's tester makes per test frame. Without
`--model_name` the weights are the initial ones: the same work per ray, other pictures.

    OMP_NUM_THREADS=2 $OFFICIAL/venv/bin/python benchmarks/speed/release_render.py --train_num 9002 --frames 1 \
        --official_src $OFFICIAL/simplenerf_official/src --run_root $OFFICIAL/official_run

`--rows R` renders only the top R rows of the frame (a smoke test: the work per ray is the same).
"""

import argparse
import json
import os
import resource
import statistics
import sys
import time
import types
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--official_src", required=True, help="the release's src/ folder (an extracted copy)")
    ap.add_argument("--run_root", required=True, help="driver.py's run root (holds data/ and runs/)")
    ap.add_argument("--train_num", type=int, default=9002, help="a training folder written by driver.py")
    ap.add_argument("--scene", default="fern")
    ap.add_argument("--model_name", default=None, help="a checkpoint in <train>/<scene>/saved_models (default: none)")
    ap.add_argument("--frame", type=int, default=0, help="frame number to render (fern's test frames: 0, 8, 16)")
    ap.add_argument("--frames", type=int, default=1, help="timed renders of the frame")
    ap.add_argument("--warmup", type=int, default=0, help="untimed renders first")
    ap.add_argument("--rows", type=int, default=None, help="render only the top ROWS rows (smoke test)")
    ap.add_argument("--threads", type=int, default=None, help="torch.set_num_threads (default: OMP_NUM_THREADS)")
    ap.add_argument("--device", choices=["cpu", "cuda"], default="cpu")
    ap.add_argument("--json_out", default=None)
    args = ap.parse_args()
    json_out = Path(args.json_out).resolve() if args.json_out else None

    sys.dont_write_bytecode = True  # nothing written into the release's tree
    sys.path.insert(0, str(Path(args.official_src).resolve()))
    os.chdir(Path(args.run_root) / "src")  # the release's paths are relative: ../data, ../runs
    if args.device == "cpu":
        os.environ["CUDA_VISIBLE_DEVICES"] = ""
    import numpy
    import torch

    if args.threads:
        torch.set_num_threads(args.threads)
    sys.modules.setdefault("skvideo", types.ModuleType("skvideo"))  # imported by the entry script only
    import Tester01

    train_dir = Path("..") / f"runs/training/train{args.train_num:04}"
    train_configs = json.loads((train_dir / "Configs.json").read_text())
    model_configs = json.loads((train_dir / args.scene / "ModelConfigs.json").read_text())
    train_configs["data_loader"]["scene_id"] = args.scene
    train_configs["device"] = [0]
    height, width = model_configs["resolution"]
    if args.rows:
        model_configs["resolution"] = [args.rows, width]
    test_configs = {"database_dirpath": train_configs["database_dirpath"].removeprefix("databases/"), "device": [0]}
    tester = Tester01.NerfTester(train_configs, model_configs, test_configs, Path(".."))
    if args.model_name:
        tester.load_model(train_dir / args.scene / "saved_models" / args.model_name)
    tester.model.eval()

    scene_dir = Path("..") / "data" / train_configs["database_dirpath"] / "all/database_data" / args.scene
    extrinsics = numpy.loadtxt(scene_dir / "CameraExtrinsics.csv", delimiter=",").reshape((-1, 4, 4))
    suffix = train_configs["data_loader"]["resolution_suffix"]
    intrinsics = numpy.loadtxt(scene_dir / f"CameraIntrinsics{suffix}.csv", delimiter=",").reshape((-1, 3, 3))

    def cpu_seconds() -> float:
        usage = resource.getrusage(resource.RUSAGE_SELF)
        return usage.ru_utime + usage.ru_stime

    seconds, cpu = [], []
    for _ in range(args.warmup + args.frames):
        if args.device == "cuda":
            torch.cuda.synchronize()
        start, cpu_start = time.perf_counter(), cpu_seconds()
        prediction = tester.predict_frame(extrinsics[args.frame], intrinsic=intrinsics[args.frame])
        if args.device == "cuda":
            torch.cuda.synchronize()
        seconds.append(time.perf_counter() - start)
        cpu.append(cpu_seconds() - cpu_start)
    timed = seconds[args.warmup :]
    rays = int(prediction["image"].shape[0] * prediction["image"].shape[1])
    model_cfg = train_configs["model"]
    per_ray = model_cfg["coarse_mlp"]["num_samples"] * 2 + model_cfg["fine_mlp"]["num_samples"]
    record = {
        "benchmark": "release_render",
        "train_num": args.train_num,
        "model_name": args.model_name,
        "frame": args.frame,
        "frame_shape": [int(prediction["image"].shape[0]), int(prediction["image"].shape[1])],
        "full_frame_shape": [height, width],
        "rays_per_frame": rays,
        "chunk": model_cfg["chunk"],
        "netchunk": model_cfg["netchunk"],
        "threads": torch.get_num_threads(),
        "torch": torch.__version__,
        "device": args.device,
        "warmup": args.warmup,
        "frames_timed": len(timed),
        "s_per_frame": statistics.median(timed),
        "s_per_frame_min": min(timed),
        "s_per_frame_max": max(timed),
        "s_per_frame_all": [round(s, 4) for s in timed],
        "warmup_s": [round(s, 4) for s in seconds[: args.warmup]],
        "cpu_s_per_frame": statistics.median(cpu[args.warmup :]),
        "rays_per_s": rays * len(timed) / sum(timed),
        "field_evaluations_per_ray": per_ray,
        "field_evaluations_per_s": per_ray * rays * len(timed) / sum(timed),
        "peak_rss_gib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20,
        "peak_cuda_gib": torch.cuda.max_memory_allocated() / 2**30 if args.device == "cuda" else None,
    }
    print(json.dumps(record), flush=True)
    if json_out:
        json_out.parent.mkdir(parents=True, exist_ok=True)
        json_out.write_text(json.dumps(record) + "\n")


if __name__ == "__main__":
    main()

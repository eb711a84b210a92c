"""The authors' release, run in this process: its published config, trainer, model and data, imported from a copy.

Nothing of the release is copied here. `import_release` puts its `src/` on `sys.path` (no bytecode is written into
it; its published configs are captured by `release_config`), and `build_trainer` builds what its
`Trainer01.start_training` builds (data loader, data preprocessor, model, loss computer, Adam, learning-rate decayer,
`Trainer01.Trainer`), without its training loop. The release's paths are relative (`../data`, `../runs`), so the
process works in `<run_root>/src` of a layout made by `layouts.build_llff_layout`.
"""

from __future__ import annotations

import os
import sys
import types
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import torch

if TYPE_CHECKING:  # layouts imports pandas, which the training-step checks and their tests do not need
    from benchmarks.equivalence.layouts import ReleaseRepo


def import_release(release_src: Path) -> None:
    """Makes the release's modules importable (`Trainer01`, `models.SimpleNeRF01`, ...) from its `src/` folder."""
    release_src = Path(release_src).resolve()
    if not (release_src / "Trainer01.py").is_file():
        raise SystemExit(f"{release_src} is not the release's src/ folder (no Trainer01.py): pass the src/ of a copy "
                         "of github.com/NagabhushanSN95/SimpleNeRF at c429746")
    sys.dont_write_bytecode = True  # nothing is written into the release's tree
    if str(release_src) not in sys.path:
        sys.path.insert(0, str(release_src))
    # skvideo is imported at module level by the entry scripts, used only for test videos (as driver.py stubs it).
    skvideo = types.ModuleType("skvideo")
    skvideo.io = types.ModuleType("skvideo.io")
    sys.modules.setdefault("skvideo", skvideo)
    sys.modules.setdefault("skvideo.io", skvideo.io)


@contextmanager
def working_dir(path: Path):
    """The release's relative paths resolve from `<run_root>/src`."""
    previous = os.getcwd()
    path.mkdir(parents=True, exist_ok=True)
    os.chdir(path)
    try:
        yield
    finally:
        os.chdir(previous)


@contextmanager
def release_device(device: torch.device):
    """Within: the release puts its model and data on `device`. Its classes take their device in `__init__` from
    `utils.CommonUtils01.get_device(config["device"])` (cuda:<first of the list> when CUDA is available, else the
    CPU; `Trainer01.Trainer`, `DataPreprocessor01`, `Tester01`), and the preprocessor repeats its common data
    `len(config["device"])` times, so the config keeps `device: [0]` (one copy) and `get_device` is replaced for the
    construction: the release on the CPU on a CUDA machine too, or on the GPU that ours uses."""
    import utils.CommonUtils01 as common

    original = common.get_device
    common.get_device = lambda _configured: device
    try:
        yield
    finally:
        common.get_device = original


@dataclass
class ReleaseRun:
    """What the release's `Trainer01.start_training` builds for one scene."""

    config: dict
    trainer: object  # Trainer01.Trainer
    model: torch.nn.Module  # models.SimpleNeRF01.SimpleNeRF (not wrapped in DataParallel)
    data: object  # data_preprocessors.DataPreprocessor01.DataPreprocessor, mode "train"
    loss_computer: object
    optimizer: torch.optim.Optimizer
    lr_decayer: object


def build_trainer(config: dict, run_root: Path, train_num: int = 9100,
                  device: torch.device = torch.device("cpu")) -> ReleaseRun:
    """The release's trainer for `config` (its `data_loader.scene_names[0]`), as `Trainer01.start_training` builds it
    (seeded with `config["seed"]` by its `init_seeds`), with its model and batches on `device` (`release_device`);
    the model is not wrapped in `DataParallel`, which with one device calls the module directly anyway."""
    import Trainer01

    config = dict(config, train_num=train_num, device=[0], resume_training=True)
    scene = config["data_loader"]["scene_names"][0]
    with working_dir(Path(run_root) / "src"), release_device(device):
        root = Path("../")
        database = root / "data" / config["database_dirpath"]
        output = root / f"runs/training/train{train_num:04}" / scene
        output.mkdir(parents=True, exist_ok=True)
        Trainer01.init_seeds(config["seed"])
        config["data_loader"]["scene_id"] = scene
        config["root_dirpath"], config["output_dirpath"] = root, output
        loader = Trainer01.get_data_loader(config, database, mode="train")
        data = Trainer01.get_data_preprocessor(config, mode="train", raw_data_dict=loader.load_data())
        model = Trainer01.get_model(config, data.get_model_configs())
        losses = Trainer01.LossComputer(config)
        optimizer = torch.optim.Adam(list(model.parameters()), lr=config["optimizer"]["lr_initial"],
                                     betas=(config["optimizer"]["beta1"], config["optimizer"]["beta2"]))
        lr_decayer = Trainer01.get_lr_decayer(config)
        trainer = Trainer01.Trainer(config, data.get_model_configs(), data, None, model, losses, optimizer,
                                    lr_decayer, output.resolve(), config["device"], verbose_log=False)
    return ReleaseRun(config, trainer, model, data, losses, optimizer, lr_decayer)


DEMOS = {2: "demo1a", 3: "demo1b", 4: "demo1c"}  # the release's published 2 / 3 / 4-view configs


def release_config(repo: ReleaseRepo, kind: str, n_views: int) -> dict:
    """The release's published training config for `n_views` views (its entry script's demo function), captured
    by stopping its first `start_training` call, as ../shared/tools/official_timing/driver.py does."""
    # skvideo is imported by the entry scripts for writing test videos only.
    sys.modules.setdefault("skvideo", types.ModuleType("skvideo"))
    sys.modules.setdefault("skvideo.io", types.ModuleType("skvideo.io"))
    entry = repo.import_module("NerfLlffTrainerTester01" if kind == "llff" else "RealEstateTrainerTester01")
    captured = {}

    class Captured(Exception):
        pass

    def capture(configs):
        captured["configs"] = configs
        raise Captured

    # `entry` is the release's entry script, patched by name: not every script defines every stage.
    saved = {k: getattr(entry, k) for k in ("start_training", "start_testing", "start_testing_videos",
                                            "start_testing_static_videos") if hasattr(entry, k)}
    entry.start_training = capture
    for k in saved:
        if k != "start_training":
            setattr(entry, k, lambda *a, **kw: None)
    try:
        getattr(entry, DEMOS[n_views])()
    except Captured:
        pass
    finally:
        for k, v in saved.items():
            setattr(entry, k, v)
    configs = captured["configs"]
    configs["device"] = [0]  # CommonUtils01.get_device: cuda:0 if CUDA is available, else the CPU
    return configs


def run_release(repo: ReleaseRepo, configs: dict, data_dir: Path, scene_id: str, make_csvs) -> dict:
    """The release's loaders and preprocessors for modes train and validation, on scene `scene_id`.

    `make_csvs(train_frame_nums)` writes the sparse-depth CSVs before the train loader reads them.
    """
    loader_factory = repo.import_module("data_loaders.DataLoaderFactory")
    preprocessor_factory = repo.import_module("data_preprocessors.DataPreprocessorFactory")
    configs["data_loader"]["scene_id"] = scene_id  # as Trainer01.start_training sets it per scene
    with release_device(torch.device("cpu")):  # the data rows compare on the CPU, also on a CUDA machine
        return _run_release(loader_factory, preprocessor_factory, configs, data_dir, make_csvs)


def _run_release(loader_factory, preprocessor_factory, configs: dict, data_dir: Path, make_csvs) -> dict:
    train_loader = loader_factory.get_data_loader(configs, data_dir, mode="train")
    make_csvs(train_loader.get_frame_nums())
    train = preprocessor_factory.get_data_preprocessor(configs, "train", raw_data_dict=train_loader.load_data())
    model_configs = train.get_model_configs()
    val_loader = loader_factory.get_data_loader(configs, data_dir, mode="validation")
    val = preprocessor_factory.get_data_preprocessor(configs, "validation", raw_data_dict=val_loader.load_data(),
                                                     model_configs=model_configs)
    test_frames = loader_factory.get_data_loader(configs, data_dir, mode="test").get_frame_nums()
    return {"train": train, "val": val, "model_configs": model_configs, "test_frames": test_frames}

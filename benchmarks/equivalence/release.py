"""The authors' release, run in this process: its published config, trainer, model and data, imported from a copy.

Nothing of the release is copied here. `import_release` puts its `src/` on `sys.path` (no bytecode is written into
it; its published configs are captured by `data.release_config`), and `build_trainer` builds what its
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

import torch


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

"""Every shipped YAML under configs/ parses against the real CLI (keys, types, class paths), without running."""

from pathlib import Path

import pytest

from simplenerf.cli import SimpleNeRFCLI, trainer_defaults
from simplenerf.module import SimpleNeRF

CONFIGS = sorted((Path(__file__).resolve().parents[1] / "configs").rglob("*.yaml"))


class ParseOnlyCLI(SimpleNeRFCLI):
    def instantiate_classes(self) -> None:  # parse and validate, but build nothing (data may be absent here)
        pass


def parse(config: Path, *extra: str):
    from lightning.pytorch import LightningDataModule

    cli = ParseOnlyCLI(  # args given explicitly: pytest's own argv must not be parsed
        SimpleNeRF, LightningDataModule, subclass_mode_data=True, trainer_defaults=trainer_defaults(), run=False,
        args=["--config", str(config), *extra],
    )
    return cli.config


def test_there_are_configs():
    names = {c.name for c in CONFIGS}
    assert {"llff.yaml", "demo.yaml"} <= names


@pytest.mark.parametrize("config", CONFIGS, ids=lambda p: p.name)
def test_config_parses(config):
    cfg = parse(config)
    assert cfg.data.class_path.startswith("simplenerf.")
    assert cfg.trainer.max_steps > 0


def test_paper_config_keeps_paper_settings():
    cfg = parse(Path(__file__).resolve().parents[1] / "configs" / "llff.yaml")
    nerf = cfg.model.nerf.init_args
    assert (nerf.num_coarse, nerf.num_fine, nerf.point_bands, nerf.view_bands) == (64, 128, 10, 4)
    assert (nerf.num_layers, nerf.width, nerf.skip_layer) == (8, 256, 5)
    assert cfg.model.lr == 5e-4 and cfg.trainer.max_steps == 100000
    assert cfg.data.init_args.factor == 4 and cfg.data.init_args.rays_per_batch == 2048


def test_unknown_key_is_rejected(capsys):
    with pytest.raises(SystemExit) as exit_info:
        parse(CONFIGS[0], "--model.no_such_option", "1")
    assert exit_info.value.code != 0

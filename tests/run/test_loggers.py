"""The W&B logger: its files go to the run folder unless told another."""

from __future__ import annotations

from simplenerf.run.loggers import WandbLogger


def test_the_run_folder_is_the_default_save_dir(tmp_path):
    logger = WandbLogger(offline=True)
    assert logger.save_dir is None
    logger.use_run_folder(tmp_path / "run")
    assert logger.save_dir == str(tmp_path / "run")


def test_an_explicit_save_dir_is_kept(tmp_path):
    logger = WandbLogger(offline=True, save_dir=str(tmp_path / "elsewhere"))
    logger.use_run_folder(tmp_path / "run")
    assert logger.save_dir == str(tmp_path / "elsewhere")

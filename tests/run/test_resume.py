"""The resume check's view of settings (simplenerf.run.resume): a setting that a run did not record (an option added to
the code since it was trained) passes at the current code's default and nowhere else. The CLI's resumes and their
one-line errors are in tests/run/test_faults.py."""

import copy
import dataclasses
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from simplenerf.data.llff import load_llff_scene
from simplenerf.data.synthetic import SyntheticDataModule
from simplenerf.errors import CheckpointError
from simplenerf.method.module import SimpleNeRF
from simplenerf.run.config_files import without_subcommand_keys
from simplenerf.run.resume import (
    NO_DEFAULT,
    RECORD_KEY,
    check_run_settings,
    current_class_paths,
    recorded_settings,
    scene_digest,
    setting_changes,
    setting_default,
)

CLASSES = {"model": SimpleNeRF, "data": SyntheticDataModule}
GRID = "simplenerf.model.grid.KPlanesField"


def recorded() -> dict:
    """Settings as `run_settings` records them, without the options added later in this test."""
    field = {"class_path": GRID, "init_args": {"resolutions": [32, 64], "features": 8}}
    return {
        "data_class": "simplenerf.data.synthetic.SyntheticDataModule",
        "data": {"n_views": 3, "rays_per_batch": 512},
        "model": {
            "nerf": {"class_path": "simplenerf.model.nerf.NeRF", "init_args": {"coarse": field, "num_coarse": 24}},
            "augmentations": [{"class_path": "simplenerf.method.augmentations.Augmentation",
                               "init_args": {"name": "points", "field": copy.deepcopy(field), "depth_weight": 0.1}}],
            "objective": {"supervision": "bidirectional", "coarse_fine_weight": 0.1},
            "chunk": 2048,
        },
    }


def with_(settings: dict, key: str, value) -> dict:
    """A copy with the dotted `key` set (list elements by index)."""
    settings = copy.deepcopy(settings)
    *path, last = key.split(".")
    node = settings
    for part in path:
        node = node[int(part)] if isinstance(node, list) else node[part]
    node[last] = value
    return settings


def test_defaults_are_found_through_dataclasses_class_paths_lists_and_base_classes():
    settings = recorded()
    assert setting_default(settings, "model.objective.coarse_fine_supervision", CLASSES) is None  # a dataclass field
    assert setting_default(settings, "model.objective.fine_concentration_weight", CLASSES) == 0.0
    assert setting_default(settings, "model.chunk", CLASSES) == 8192  # the module's own argument
    assert setting_default(settings, "model.nerf.init_args.coarse.init_args.depth_tv_scale", CLASSES) == 1.0
    assert setting_default(settings, "model.augmentations.0.init_args.min_ndc_z", CLASSES) is None
    assert setting_default(settings, "model.augmentations.0.init_args.stage", CLASSES) == "coarse"
    assert setting_default(settings, "model.augmentations.0.init_args.field.init_args.density_scales", CLASSES) is None
    assert setting_default(settings, "data.n_views", CLASSES) == 2  # SceneDataModule's, through **kwargs
    for key in ("model.objective.no_such_option", "model.nerf.class_path", "model.augmentations.0.init_args.name",
                "model.augmentations.3.init_args.stage", "model.nerf.init_args.no_such.init_args.x", "other.key"):
        assert setting_default(settings, key, CLASSES) is NO_DEFAULT, key
    unknown = with_(settings, "model.nerf.class_path", "simplenerf.model.no_such.Field")
    assert setting_default(unknown, "model.nerf.init_args.num_coarse", CLASSES) is NO_DEFAULT


def test_an_option_added_since_the_run_passes_at_its_default_only():
    old = recorded()
    new = with_(old, "model.objective.coarse_fine_supervision", None)
    new = with_(new, "model.augmentations.0.init_args.min_ndc_z", None)
    new = with_(new, "model.nerf.init_args.coarse.init_args.density_features", None)
    assert setting_changes(old, new, classes=CLASSES) == []
    assert setting_changes(old, new) == [  # without the classes every unrecorded setting is a change, as before
        "model.augmentations.0.init_args.min_ndc_z: (unset) -> null",
        "model.nerf.init_args.coarse.init_args.density_features: (unset) -> null",
        "model.objective.coarse_fine_supervision: (unset) -> null",
    ]
    changed = with_(new, "model.objective.coarse_fine_supervision", "one_way")
    changed = with_(changed, "model.augmentations.0.init_args.min_ndc_z", -0.5)
    assert setting_changes(old, changed, classes=CLASSES) == [
        "model.augmentations.0.init_args.min_ndc_z: (unset) -> -0.5",
        "model.objective.coarse_fine_supervision: (unset) -> one_way",
    ]


def test_recorded_settings_still_compare_whatever_the_defaults():
    old = recorded()
    # A recorded setting changed to the current default is a change: the run trained with the recorded value.
    assert setting_changes(old, with_(old, "model.chunk", 8192), classes=CLASSES) == ["model.chunk: 2048 -> 8192"]
    assert setting_changes(old, with_(old, "model.objective.coarse_fine_weight", 0.2), classes=CLASSES) == [
        "model.objective.coarse_fine_weight: 0.1 -> 0.2"]
    dropped = copy.deepcopy(old)
    del dropped["model"]["objective"]["supervision"]  # an option the code no longer has
    assert setting_changes(old, dropped, classes=CLASSES) == ["model.objective.supervision: bidirectional -> (unset)"]
    two = with_(old, "model.augmentations", old["model"]["augmentations"] * 2)  # a second augmentation
    assert setting_changes(old, two, classes=CLASSES)[0].startswith("model.augmentations.1.class_path: (unset) -> ")
    # A long path is shown whole (its end is what differs), a long list cut.
    scene = "/a/folder/long/enough/that/a/cut/after/sixty/characters/would/hide/the/scene/"
    assert setting_changes({"scene": scene + "seed0"}, {"scene": scene + "seed1"}) == [
        f"scene: {scene}seed0 -> {scene}seed1"]
    assert setting_changes({"frames": list(range(30))}, {"frames": list(range(31))}) == [
        f"frames: {str(list(range(30)))[:57]}... -> {str(list(range(31)))[:57]}..."]
    resized = with_(old, "model.nerf.init_args.coarse.init_args.resolutions", [32, 64, 128])  # a list of numbers
    assert setting_changes(old, resized, classes=CLASSES) == [
        "model.nerf.init_args.coarse.init_args.resolutions: [32, 64] -> [32, 64, 128]"]


def test_a_run_from_before_the_move_reads_its_class_paths_as_the_current_ones(tmp_path):
    """Issue 37 moved the run machinery into simplenerf.run and the LightningModule's optimiser into
    simplenerf.method: a run's config.yaml and checkpoint written before name the old class paths."""
    old = {"model": {"lr_scheduler": {"class_path": "simplenerf.optim.ExponentialDecay"}},
           "trainer": {"callbacks": [{"class_path": "simplenerf.callbacks.LossWeightSchedule"},
                                     {"class_path": "simplenerf.viz.renders.ValidationRenders"}],
                       "logger": {"class_path": "simplenerf.loggers.WandbLogger"}},
           "note": "simplenerf.callbacks.are.not.a.class"}
    assert current_class_paths(old) == {
        "model": {"lr_scheduler": {"class_path": "simplenerf.method.optim.ExponentialDecay"}},
        "trainer": {"callbacks": [{"class_path": "simplenerf.run.callbacks.LossWeightSchedule"},
                                  {"class_path": "simplenerf.run.callbacks.ValidationRenders"}],
                    "logger": {"class_path": "simplenerf.run.loggers.WandbLogger"}},
        "note": "simplenerf.callbacks.are.not.a.class",
    }
    checkpoint = {RECORD_KEY: {"settings": {"model": old["model"]}}}
    assert recorded_settings(checkpoint) == {"model": {"lr_scheduler": {
        "class_path": "simplenerf.method.optim.ExponentialDecay"}}}
    # The CLI gives such a config.yaml to the parser with the current paths; a current one goes as the file itself.
    file = tmp_path / "config.yaml"
    file.write_text(yaml.safe_dump(old))
    (given,) = [a for a in without_subcommand_keys(["--config", str(file)], ()) if a != "--config"]
    assert yaml.safe_load(given) == current_class_paths(old)
    file.write_text(yaml.safe_dump(current_class_paths(old)))
    assert without_subcommand_keys(["--config", str(file)], ()) == ["--config", str(file)]


def test_a_scene_is_its_content_wherever_its_folder_is(synthetic_scene, tmp_path):
    """The digest is of the image names and poses: a copy elsewhere has the same, other poses or names do not."""
    scene = load_llff_scene(synthetic_scene, 1, 3)
    digest = scene_digest(scene)
    assert len(digest) == 16 and int(digest, 16) >= 0
    copied = Path(shutil.copytree(synthetic_scene, tmp_path / "copied"))
    assert scene_digest(load_llff_scene(copied, 1, 3)) == digest
    # The poses as the file gives them: the same for another split (the loaded ones are recentred on the train views).
    assert scene_digest(load_llff_scene(copied, 1, 2)) == digest
    # A format that does not give its files' cameras: the loaded ones, which the split moves.
    loaded = dataclasses.replace(scene, file_cameras=None)
    assert scene_digest(loaded) != digest
    assert scene_digest(loaded) == scene_digest(dataclasses.replace(load_llff_scene(copied, 1, 3), file_cameras=None))
    assert scene_digest(loaded) != scene_digest(dataclasses.replace(load_llff_scene(copied, 1, 2), file_cameras=None))
    poses = np.load(copied / "poses_bounds.npy")
    poses[4, 3] += 0.05  # frame 4's camera moved along x
    np.save(copied / "poses_bounds.npy", poses)
    assert scene_digest(load_llff_scene(copied, 1, 3)) != digest
    renamed = Path(shutil.copytree(synthetic_scene, tmp_path / "renamed", ignore=shutil.ignore_patterns("depths")))
    (renamed / "images" / "019.png").rename(renamed / "images" / "020.png")
    assert scene_digest(load_llff_scene(renamed, 1, 3)) != digest


def scene_settings(folder: str, digest: str | None) -> dict:
    """Settings as `run_settings` records them for a scene in `folder` (`digest`: None, as recorded before it)."""
    settings = {"data_class": "simplenerf.data.llff.LLFFDataModule", "data": {"n_views": 3},
                "scene": {"scene": folder, "factor": 4}, "train_frames": [0, 9, 18], "size": [48, 64]}
    return settings if digest is None else {**settings, "scene_digest": digest}


def check(recorded: dict, current: dict, subcommand: str = "fit", allowed: tuple[str, ...] = ()) -> None:
    checkpoint = {RECORD_KEY: {"settings": recorded}, "global_step": 8}
    check_run_settings(subcommand, Path("run/checkpoints/last.ckpt"), checkpoint, current, allowed, CLASSES)


def test_a_moved_scene_resumes_and_says_so_other_content_or_an_old_record_of_another_folder_stops(capsys):
    check(scene_settings("/data/fern", "00aa"), scene_settings("/data/fern", "00aa"))
    assert capsys.readouterr().err == ""
    # | the same scene in another folder | one line on stderr, for a resume and for a test |
    for subcommand, doing in (("fit", "resuming"), ("test", "testing")):
        check(scene_settings("/data/fern", "00aa"), scene_settings("/scratch/fern", "00aa"), subcommand)
        assert capsys.readouterr().err == (f"simplenerf: scene folder moved: /data/fern -> /scratch/fern (the same "
                                           f"image names and poses); {doing} the run there\n")
    # | other poses or image names, in the same folder or another | a difference, named |
    refusal = ("this resume differs from the run of checkpoint run/checkpoints/last.ckpt (step 8) in {listed} (the "
               "scene's image names or poses are not those the run trained on); use the run's settings (its "
               "config.yaml), start a new run in another folder, or accept the change with --allow_changes [{keys}]")
    with pytest.raises(CheckpointError) as error:
        check(scene_settings("/data/fern", "00aa"), scene_settings("/data/fern", "00bb"))
    assert str(error.value) == refusal.format(listed="scene_digest: 00aa -> 00bb", keys="scene_digest")
    with pytest.raises(CheckpointError) as error:
        check(scene_settings("/data/fern", "00aa"), scene_settings("/scratch/fern", "00bb"))
    assert str(error.value) == refusal.format(listed="scene.scene: /data/fern -> /scratch/fern; scene_digest: 00aa -> "
                                              "00bb", keys="scene.scene, scene_digest")
    check(scene_settings("/data/fern", "00aa"), scene_settings("/data/fern", "00bb"), allowed=("scene_digest",))
    # | a run recorded before the digest | its folder compared as before: the same folder passes, another stops |
    check(scene_settings("/data/fern", None), scene_settings("/data/fern", "00aa"))
    with pytest.raises(CheckpointError, match=r" in scene\.scene: /data/fern -> /scratch/fern; use the run's "):
        check(scene_settings("/data/fern", None), scene_settings("/scratch/fern", "00aa"), "test")
    assert capsys.readouterr().err == ""

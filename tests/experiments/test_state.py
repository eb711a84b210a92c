"""simplenerf.experiments.state: what a run's folder says about its job."""

import torch

from simplenerf.experiments.state import checkpoint_steps


def test_checkpoint_steps_reads_the_periodic_names_and_the_step_saved_in_last(tmp_path):
    checkpoints = tmp_path / "checkpoints"
    assert checkpoint_steps(tmp_path) is None
    checkpoints.mkdir()
    for step in (400, 800):
        (checkpoints / f"step{step:06d}.ckpt").write_bytes(b"")  # periodic checkpoints: the name is enough
    (checkpoints / "stepfinal.ckpt").write_bytes(b"")
    assert checkpoint_steps(tmp_path) == 800
    # a fit stopped by a signal at step 1084 saved last.ckpt there, past the last periodic checkpoint
    torch.save({"global_step": 1084, "state_dict": {"w": torch.zeros(3)}}, checkpoints / "last.ckpt")
    assert checkpoint_steps(tmp_path) == 1084
    torch.save({"global_step": 400, "state_dict": {}}, checkpoints / "last.ckpt")  # older: the newer name stands
    assert checkpoint_steps(tmp_path) == 800


def test_checkpoint_steps_ignores_a_last_checkpoint_it_cannot_read(tmp_path):
    checkpoints = tmp_path / "checkpoints"
    checkpoints.mkdir()
    (checkpoints / "last.ckpt").write_bytes(b"PK\x03\x04 half written")
    assert checkpoint_steps(tmp_path) is None
    (checkpoints / "step000400.ckpt").write_bytes(b"")
    assert checkpoint_steps(tmp_path) == 400

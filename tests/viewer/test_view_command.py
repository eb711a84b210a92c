"""`simplenerf view` on bad input: one `simplenerf: error:` line, exit status 2."""

import socket

import torch
import yaml

from tests.run.test_cli import run, run_args


def error_line(proc) -> str:
    assert proc.returncode == 2, proc.stderr[-2000:]
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    return lines[0]


def test_a_run_folder_without_a_checkpoint(tmp_path):
    (tmp_path / "config.yaml").write_text("{}")
    line = error_line(run("view", str(tmp_path), check=False))
    assert line == (f"simplenerf: error: run folder {tmp_path} has no checkpoint ({tmp_path}/checkpoints/*.ckpt): "
                    "train it first (`simplenerf fit ...`), or give a checkpoint file")


def test_a_path_that_is_neither(tmp_path):
    line = error_line(run("view", str(tmp_path / "nothing"), check=False))
    assert line == f"simplenerf: error: {tmp_path / 'nothing'} is neither a run folder nor a checkpoint file"


def test_a_port_in_use_for_view_and_for_fit(viewer_run, tmp_path):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        expected = (f"simplenerf: error: port {port} on 127.0.0.1 is in use (Address already in use): choose another "
                    "with --port N, or --port 0 for any free one")
        assert error_line(run("view", str(viewer_run[0]), "--port", str(port), check=False)) == expected
        fit = run("fit", *run_args(tmp_path, viewer_run[0].parent), "--trainer.max_steps", "1", "--viewer", "true",
                  "--viewer_port", str(port), check=False)  # (the scene and SfM of the fixture's run)
        assert error_line(fit) == expected
        assert not (tmp_path / "run" / "checkpoints").exists()  # stopped before anything was written


def test_a_checkpoint_that_does_not_fit_its_config(viewer_run, tmp_path):
    folder = tmp_path / "other"
    (folder / "checkpoints").mkdir(parents=True)
    config = yaml.safe_load((viewer_run[0] / "config.yaml").read_text())
    config["trainer"]["default_root_dir"] = str(folder)  # its own run, not a copy of viewer_run (a notice of its own)
    (folder / "config.yaml").write_text(yaml.safe_dump(config))
    state = torch.load(viewer_run[0] / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=False)
    name = "nerf.fine.trunk.0.weight"
    assert name in state["state_dict"]
    state["state_dict"][name] = torch.zeros(3, 3)
    torch.save(state, folder / "checkpoints" / "last.ckpt")
    line = error_line(run("view", str(folder), "--port", "0", check=False))
    assert line.startswith(f"simplenerf: error: checkpoint {folder}/checkpoints/last.ckpt does not fit the model: "
                           f"{name} is (3, 3) in it but ")

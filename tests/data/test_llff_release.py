"""`simplenerf download llff` through the real command, from a local HTTP server (tests/data/local_server.py) serving
a zip made here from the synthetic generator's scenes in the LLFF layout: --dry_run, a download cut off halfway and
resumed, only the chosen scenes and factors unpacked and checked as `fit` checks them, the manifest, a rerun that skips,
a wrong checksum, a scene the archive lacks and a broken archive. No network beyond 127.0.0.1."""

from __future__ import annotations

import hashlib
import io
import json
import sys
import types
import zipfile
from pathlib import Path

import pytest

from simplenerf.data.llff import load_llff_scene
from simplenerf.data.llff_release import ARCHIVE_EXPECTED, DRIVE_FILE_ID, PAPER_SCENES
from simplenerf.synthetic.generate import make_synthetic_scene
from tests.data.download_command import run_download
from tests.data.local_server import LocalServer


def llff_zip(root: Path) -> bytes:
    """nerf_llff_data.zip as the release lays it out (nerf_llff_data/<scene>/...), two synthetic scenes at factors
    1, 4 and 8 with their depth maps, which `download llff` must leave packed."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as zf:
        for name, seed in (("fern", 0), ("horns", 1)):
            scene = make_synthetic_scene(root / name, height=64, width=96, n_frames=9, factors=(1, 4, 8), seed=seed)
            for path in sorted(scene.rglob("*")):
                if path.is_file():
                    zf.write(path, f"nerf_llff_data/{name}/{path.relative_to(scene).as_posix()}")
    return buffer.getvalue()


@pytest.fixture(scope="module")
def archive(tmp_path_factory) -> bytes:
    return llff_zip(tmp_path_factory.mktemp("llff_zip"))


@pytest.fixture()
def server(archive):
    with LocalServer() as s:
        s.behaviour.files["/nerf_llff_data.zip"] = archive
        yield s


def download(*args: str) -> int:
    """Runs `simplenerf download llff ARGS` in this process; its exit status."""
    return run_download("llff", *args)


def test_the_release_is_named_and_no_checksum_is_invented():
    assert DRIVE_FILE_ID == "16VnMcF1KJYxN9QId6TClMsZRahHNMW5g"
    assert ARCHIVE_EXPECTED.size is None and ARCHIVE_EXPECTED.sha256 is None
    assert PAPER_SCENES == ("fern", "flower", "fortress", "horns", "leaves", "orchids", "room", "trex")


def test_dry_run_says_what_how_big_and_where_and_writes_nothing(server, archive, tmp_path, capsys):
    dest = tmp_path / "data" / "nerf_llff_data"
    assert download("--url", server.url("/nerf_llff_data.zip"), "--dest", str(dest), "--scenes", "fern",
                    "--dry_run") == 0
    out = capsys.readouterr().out
    assert f"archive:  {tmp_path / 'data' / 'nerf_llff_data.zip'} (to download, " in out
    assert f"kB ({len(archive)} bytes))" in out
    assert "unpack:   images_4/images_8 and poses_bounds.npy into" in out
    assert "  fern       unpack" in out
    assert not (tmp_path / "data").exists()
    assert [r[0] for r in server.behaviour.requests] == ["HEAD"]


def test_cut_download_resumes_and_only_chosen_scenes_are_unpacked_and_checked(server, archive, tmp_path, capsys):
    dest, sha = tmp_path / "data" / "nerf_llff_data", hashlib.sha256(archive).hexdigest()
    args = ["--url", server.url("/nerf_llff_data.zip"), "--dest", str(dest), "--scenes", "fern", "--sha256", sha]
    server.behaviour.cut_after = len(archive) // 2
    assert download(*args) == 2
    err = capsys.readouterr().err
    assert f"the connection closed after {len(archive) // 2} of {len(archive)} bytes; run the same command" in err
    assert len(err.strip().splitlines()) == 1 and err.startswith("simplenerf: error: ")
    assert not dest.exists() and not (tmp_path / "data" / "nerf_llff_data.zip").exists()

    assert download(*args) == 0
    out = capsys.readouterr().out
    assert server.behaviour.requests[-1] == ("GET", "/nerf_llff_data.zip", f"bytes={len(archive) // 2}-")
    assert f"{len(archive)} bytes, SHA-256 {sha} (checked)" in out
    assert f"fern: 9 frames (images_4 24x16, images_8 12x8) -> {dest / 'fern'}" in out
    assert sorted(p.name for p in dest.iterdir()) == ["fern", "manifest.json"]  # no horns, no partial folder
    assert sorted(p.name for p in (dest / "fern").iterdir()) == ["images_4", "images_8", "poses_bounds.npy"]
    scene = load_llff_scene(dest / "fern", factor=4, n_views=2)  # what `fit` reads
    assert scene.views.images.shape == (9, 16, 24, 3)
    manifest = json.loads((dest / "manifest.json").read_text())
    assert manifest["archive"] == {"name": "nerf_llff_data.zip", "source": server.url("/nerf_llff_data.zip"),
                                   "size": len(archive), "sha256": sha}
    assert manifest["scenes"] == {"fern": {"frames": 9, "images": {"images_4": "24x16", "images_8": "12x8"}}}

    count = len(server.behaviour.requests)
    assert download(*args) == 0
    assert "all 1 scenes are complete" in capsys.readouterr().out
    assert len(server.behaviour.requests) == count  # nothing fetched again

    assert download(*args[:-4], "--scenes", "all", "--factors", "8") == 0  # the kept archive, another scene
    assert "horns: 9 frames (images_8 12x8)" in capsys.readouterr().out
    assert len(server.behaviour.requests) == count
    assert sorted(json.loads((dest / "manifest.json").read_text())["scenes"]) == ["fern", "horns"]


def test_wrong_checksum_leaves_nothing(server, tmp_path, capsys):
    dest = tmp_path / "data" / "nerf_llff_data"
    assert download("--url", server.url("/nerf_llff_data.zip"), "--dest", str(dest), "--sha256", "ab" * 32) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("simplenerf: error: ") and len(err.splitlines()) == 1
    assert f"expected {'ab' * 32}; deleted it" in err
    assert list((tmp_path / "data").iterdir()) == []


def test_a_scene_the_archive_lacks_is_named_before_anything_is_unpacked(server, tmp_path, capsys):
    dest = tmp_path / "data" / "nerf_llff_data"
    assert download("--url", server.url("/nerf_llff_data.zip"), "--dest", str(dest), "--scenes", "fern",
                    "flower") == 2
    assert "has no scene flower; it has: fern, horns" in capsys.readouterr().err
    assert not dest.exists()
    assert download("--url", server.url("/nerf_llff_data.zip"), "--dest", str(dest), "--scenes", "fern",
                    "--factors", "2") == 2
    assert "scene fern of the archive has no images_2 (choose others with --factors)" in capsys.readouterr().err
    assert not dest.exists() or list(dest.iterdir()) == []


def test_an_incomplete_scene_folder_is_reported_not_overwritten(tmp_path, capsys):
    dest = tmp_path / "nerf_llff_data"
    (dest / "fern").mkdir(parents=True)
    assert download("--dest", str(dest), "--scenes", "fern") == 2
    err = capsys.readouterr().err
    assert f"{dest / 'fern'} exists but is not a complete scene ({dest / 'fern' / 'poses_bounds.npy'} is missing" in err
    assert list((dest / "fern").iterdir()) == []


def test_a_broken_archive_is_one_line(tmp_path, capsys):
    archive = tmp_path / "nerf_llff_data.zip"
    archive.write_bytes(b"PK not really a zip")
    assert download("--archive", str(archive), "--dest", str(tmp_path / "out"), "--scenes", "fern") == 2
    assert f"cannot read {archive} as a zip archive" in capsys.readouterr().err


def test_google_drive_goes_through_gdown_with_resume(archive, tmp_path, monkeypatch, capsys):
    """gdown replaced by a stub: called with the release's file id and resume=True, its output checked and renamed."""
    calls = []

    def fake_download(id: str, output: str, quiet: bool, resume: bool) -> str:  # noqa: A002 (gdown's name)
        calls.append((id, Path(output).name, resume))
        Path(output).write_bytes(archive)
        return output

    monkeypatch.setitem(sys.modules, "gdown", types.SimpleNamespace(download=fake_download))
    dest = tmp_path / "data" / "nerf_llff_data"
    assert download("--dest", str(dest), "--scenes", "horns", "--factors", "8") == 0
    assert calls == [(DRIVE_FILE_ID, "nerf_llff_data.zip.unchecked", True)]
    assert (tmp_path / "data" / "nerf_llff_data.zip").read_bytes() == archive
    assert "not checked: none is published; pass --sha256 to check it" in capsys.readouterr().out
    assert sorted(p.name for p in (dest / "horns").iterdir()) == ["images_8", "poses_bounds.npy"]
    monkeypatch.setitem(sys.modules, "gdown", None)  # not installed
    assert download("--dest", str(tmp_path / "other"), "--scenes", "fern") == 2
    assert "downloading from Google Drive needs gdown: pip install 'simplenerf[data]'" in capsys.readouterr().err

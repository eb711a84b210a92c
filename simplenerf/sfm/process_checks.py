"""What `process-data` checks besides running SfM: its output folder (never its input; `--overwrite` replaces only
what an earlier process-data wrote, listed in its marker file) and its own result (`judge`: a camera or a
registration that SfM reports as a success but that is not plausible)."""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from simplenerf.errors import DataError, unwritable

MARKER = ".simplenerf-process-data.json"  # what process-data wrote into its output (what --overwrite may replace)
# A plausible camera (`judge`): horizontal field of view, focal length against the EXIF prior, radial distortion.
FOV_RANGE_DEG = (10.0, 140.0)
PRIOR_RATIO = 2.0
MAX_RADIAL = 0.5


def judge(report: dict) -> list[str]:
    """Problems of a result that structure from motion reports as a success: a focal length far from the EXIF prior
    (more than `PRIOR_RATIO` x) or an implausible field of view (outside `FOV_RANGE_DEG`), extreme radial distortion
    (|k| > `MAX_RADIAL`), or photos that register in disjoint groups (only the largest is the scene). Photos of
    several scenes, or with too little overlap, give such cameras (e.g. 6x the focal length, k = 13.7)."""
    problems = []
    height, width = report["size"]
    prior = report.get("exif_focal_px")
    for camera in report["cameras"]:
        params = dict(zip(camera["param_names"].split(", "), camera["params"], strict=False))
        focal = params.get("f", params.get("fx"))
        if focal is None:
            continue
        fov = float(np.degrees(2 * np.arctan(width / (2 * focal))))
        if not FOV_RANGE_DEG[0] <= fov <= FOV_RANGE_DEG[1]:
            problems.append(f"the camera's focal length {focal:.0f} px is a {fov:.1f} deg field of view, outside a "
                            f"plausible {FOV_RANGE_DEG[0]:g}-{FOV_RANGE_DEG[1]:g} deg")
        if prior and not 1 / PRIOR_RATIO <= focal / prior <= PRIOR_RATIO:
            problems.append(f"the camera's focal length {focal:.0f} px is {focal / prior:.2g} x the EXIF focal length "
                            f"{prior:.0f} px")
        radial = [abs(v) for k, v in params.items() if k in ("k", "k1", "k2")]
        if radial and max(radial) > MAX_RADIAL:
            problems.append(f"the camera's radial distortion {max(radial):.3g} is extreme (over {MAX_RADIAL:g})")
    groups = next((a.get("groups") for a in report["attempts"] if a["name"] == report["attempt"]), None) or []
    if len(groups) > 1:
        problems.append(f"the photos register in {len(groups)} disjoint groups ({', '.join(map(str, groups))} photos):"
                        f" only the largest is the scene")
    return problems


def check_output_folder(images_dir: Path, output_dir: Path, overwrite: bool) -> None:
    """DataError unless `output_dir` may be written: not the photo folder, inside it or containing it; empty or
    absent, or (with `overwrite`) an earlier process-data output (its `MARKER`)."""
    images, output = images_dir.resolve(), output_dir.resolve()
    if output == images:
        where = "is"
    elif images in output.parents:
        where = "is inside"
    elif output in images.parents:
        where = "contains"
    else:
        where = None
    if where:
        raise DataError(f"--output {output_dir} {where} the photo folder {images_dir}: process-data never writes into "
                        "its input; choose an --output outside it")
    if output_dir.exists() and (not output_dir.is_dir() or any(output_dir.iterdir())):
        if not overwrite:
            raise DataError(f"{output_dir} already exists; choose another --output or pass --overwrite")
        if not (output_dir / MARKER).is_file():
            raise DataError(f"{output_dir} was not written by process-data (it has no {MARKER}), so --overwrite does "
                            "not replace it; choose another --output, or empty it yourself")


def check_writable_parent(output_dir: Path) -> None:
    """DataError unless the folder that will hold `output_dir` can be created and written."""
    if (reason := unwritable(output_dir.parent)) is not None:
        raise DataError(f"cannot write the output {output_dir}: {output_dir.parent}: {reason}")


def folder_mode() -> int:
    """The mode a new folder gets under this process's umask (e.g. 0755 under umask 022)."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o777 & ~mask


def _safe(name: str) -> bool:
    """A relative path inside the output (no absolute path, no `..`)."""
    parts = Path(name).parts
    return bool(parts) and not Path(name).is_absolute() and ".." not in parts


def earlier_files(output_dir: Path) -> list[str]:
    """The files (relative paths) an earlier process-data wrote into `output_dir`, from its marker: its `files`; a
    marker written before they were listed names top-level `entries`, of which a folder counts with the PNG images in
    it (all process-data writes there), so a user's other files in it stay."""
    try:
        marker = json.loads((output_dir / MARKER).read_text())
    except (OSError, ValueError):
        return []
    if not isinstance(marker, dict):
        return []
    if isinstance(marker.get("files"), list):
        return [str(name) for name in marker["files"] if _safe(str(name))]
    files = []
    for name in (str(n) for n in marker.get("entries", []) if _safe(str(n))):
        path = output_dir / name
        if path.is_dir():
            files += [p.relative_to(output_dir).as_posix() for p in path.glob("*.png") if p.is_file()]
        else:
            files.append(name)
    return files


def replace_output(partial: Path, output_dir: Path) -> None:
    """Moves the files of `partial` into `output_dir`. In an existing output exactly the files an earlier
    process-data listed in its marker are replaced or removed (moved aside first, deleted at the end), and the
    folders they leave empty; every other file stays, also one a user put into `images/`."""
    if not output_dir.exists():
        os.replace(partial, output_dir)
        return
    new = sorted(p.relative_to(partial).as_posix() for p in partial.rglob("*") if p.is_file())
    old = Path(tempfile.mkdtemp(prefix=f".{output_dir.name}.old-", dir=output_dir.parent))
    try:
        moved_aside = []
        for name in sorted({*earlier_files(output_dir), *new}):
            path = output_dir / name
            if path.is_file() or path.is_symlink():
                (old / name).parent.mkdir(parents=True, exist_ok=True)
                os.replace(path, old / name)
                moved_aside.append(name)
        for name in new:
            (output_dir / name).parent.mkdir(parents=True, exist_ok=True)
            os.replace(partial / name, output_dir / name)
        folders = {parent for name in moved_aside for parent in Path(name).parents if parent != Path(".")}
        for folder in sorted(folders, key=lambda f: len(f.parts), reverse=True):  # deepest first
            try:
                (output_dir / folder).rmdir()
            except OSError:  # not empty: a new file or one of the user's
                pass
        shutil.rmtree(partial, ignore_errors=True)
    finally:
        shutil.rmtree(old, ignore_errors=True)

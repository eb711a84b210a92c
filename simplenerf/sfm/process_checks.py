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


def replace_output(partial: Path, output_dir: Path) -> None:
    """Moves the entries of `partial` into `output_dir`; in an existing output only the entries an earlier
    process-data listed in its marker are replaced (moved aside first, deleted at the end), other files stay."""
    if not output_dir.exists():
        os.replace(partial, output_dir)
        return
    earlier = []
    if (output_dir / MARKER).is_file():
        try:
            earlier = [str(name) for name in json.loads((output_dir / MARKER).read_text()).get("entries", [])]
        except (OSError, ValueError, AttributeError):
            earlier = []
    old = Path(tempfile.mkdtemp(prefix=f".{output_dir.name}.old-", dir=output_dir.parent))
    try:
        for name in {*earlier, *(p.name for p in partial.iterdir())}:
            if "/" in name or name in ("", ".", ".."):
                continue
            if (output_dir / name).exists():
                os.replace(output_dir / name, old / name)
        for entry in partial.iterdir():
            os.replace(entry, output_dir / entry.name)
        partial.rmdir()
    finally:
        shutil.rmtree(old, ignore_errors=True)

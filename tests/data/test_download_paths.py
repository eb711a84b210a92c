"""The paper's sweep files read their scenes where `simplenerf download` writes them: every LLFF scene path is
`<download llff's --dest default>/<one of the paper's scenes>`, every RealEstate-10K one `<download realestate's
--dest default>/<one of the paper's clips>`, and together they are all of them."""

from __future__ import annotations

from pathlib import Path

import yaml

from simplenerf.commands.download import llff_parser, realestate_parser
from simplenerf.data.llff_release import PAPER_SCENES
from simplenerf.data.realestate_release import PAPER_CLIPS
from tests.conftest import REPO

SWEEPS = ("llff_table1.yaml", "realestate_table1.yaml", "ablations_table3.yaml")


def test_sweep_scene_paths_are_what_the_download_commands_write():
    llff_dest = llff_parser().parse_args([]).dest
    realestate_dest = realestate_parser().parse_args([]).dest
    assert (llff_dest, realestate_dest) == (Path("data/nerf_llff_data"), Path("data/realestate10k"))
    expected = {
        "llff_table1.yaml": {llff_dest / s for s in PAPER_SCENES},
        "realestate_table1.yaml": {realestate_dest / c.id for c in PAPER_CLIPS},
        "ablations_table3.yaml": {llff_dest / s for s in PAPER_SCENES} | {realestate_dest / c.id for c in PAPER_CLIPS},
    }
    for name in SWEEPS:
        sweep = yaml.safe_load((REPO / "configs" / "sweeps" / name).read_text())
        assert {Path(scene["path"]) for scene in sweep["scenes"]} == expected[name], name

"""The package's shape: the LightningModule imports no SfM or LPIPS machinery, and no module grows past ~400 lines."""

import subprocess
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "simplenerf"


def test_importing_the_module_loads_neither_pycolmap_nor_lpips():
    code = "import sys, simplenerf.module; print(sorted({'pycolmap', 'lpips'} & set(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_no_module_is_over_400_lines():
    sizes = {str(p.relative_to(PACKAGE)): len(p.read_text().splitlines()) for p in PACKAGE.rglob("*.py")}
    assert {name: n for name, n in sizes.items() if n > 420} == {}

"""The script that draws the docs' realism picture runs against the current package (the docs'
earlier figure came from a script that had stopped running unnoticed)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from PIL import Image

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "realism_figure.py"


@pytest.mark.slow
def test_the_realism_figure_script_draws_its_three_panels_of_two_different_scans(tmp_path: Path) -> None:
    out = tmp_path / "realism.png"
    done = subprocess.run([sys.executable, str(SCRIPT), str(out)], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    with Image.open(out) as image:
        assert image.size == (1500, 560)
    paper, full = (int(part.split()[0].replace(",", "")) for part in done.stdout.split("paper ")[1].split(", full "))
    assert paper > 0 and full > 0 and paper != full  # the effects change what one station sees

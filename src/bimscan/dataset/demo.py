"""The dataset of ``bimscan demo``: generated buildings, small enough for a laptop.

Two seeded demo buildings (one and two storeys) scanned with all six of the paper's
configurations, at a head speed of 60 deg/s (the VZ-400's fastest, six times the presets'
10 deg/s: a sixth of the points, the same pulse and line rates, so the density ratios between
configurations stay the paper's). The command (``cli/dataset_commands.py``) writes this spec
beside the dataset, builds it, and makes the statistics (Figs. 4-6) and pictures (Fig. 3);
running it again resumes where it stopped.
"""

from __future__ import annotations

from pathlib import Path

_TEMPLATE = """\
# The dataset of 'bimscan demo': two generated buildings x the paper's six configurations.
# Head speed {head} deg/s instead of the presets' 10 deg/s: {ratio} of the points per station, the
# same pulse and line rates (so the same density ratios between configurations).
name = "bimscan-demo"
seed = 0
scheme = "spc5"
scanner = "riegl_vz400"
formats = ["laz"]  # add "npy" for NumPy folders too (about 30 bytes a point instead of 5)

[[scenes]]
name = "office-2f"
generate = { seed = 1, storeys = 2 }

[[scenes]]
name = "office-1f"
generate = { seed = 2, storeys = 1 }

"""
DEFAULT_HEAD_DEG_PER_S = 60.0
RENDER_CONFIG = "exp3"  # the configuration pictured for each scene


def demo_spec(*, head_deg_per_s: float = DEFAULT_HEAD_DEG_PER_S) -> str:
    """The demo's dataset spec (TOML text) at a head speed in deg/s (faster: fewer points)."""
    ratio = 10.0 / head_deg_per_s  # the presets turn at 10 deg/s
    share = f"1/{1 / ratio:g}" if ratio < 1 else f"{ratio:g} times"
    head = repr(float(head_deg_per_s))
    configs = "\n".join(f'[[configs]]\nname = "{p}"\npreset = "{p}"\nhead_deg_per_s = {head}\n'
                         for p in ("exp1", "exp2", "exp3", "exp4", "exp5", "exp6"))
    return _TEMPLATE.replace("{head}", head).replace("{ratio}", share) + configs


def write_demo_spec(path: Path, *, head_deg_per_s: float = DEFAULT_HEAD_DEG_PER_S) -> Path:
    """Write the demo's dataset spec to ``path`` (atomically); returns the path."""
    from bimscan.files import write_atomic

    write_atomic(path, demo_spec(head_deg_per_s=head_deg_per_s).encode("utf-8"))
    return path

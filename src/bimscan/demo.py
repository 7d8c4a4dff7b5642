"""``bimscan demo``: the whole pipeline on generated buildings, small enough for a laptop.

Two seeded demo buildings (one and two storeys) scanned with all six of the paper's
configurations, at a head speed of 60 deg/s (the VZ-400's fastest, six times the presets'
10 deg/s: a sixth of the points, the same pulse and line rates, so the density ratios between
configurations stay the paper's). ``run_demo`` writes this spec beside the dataset, builds it,
and makes the statistics (Figs. 4-6) and pictures (Fig. 3); running it again resumes where it
stopped.

OUT_DIR is an output folder (``bimscan.files.prepare_output_folder``): a new or empty one, or one
bimscan made; a user's file at a name the demo writes there is refused before any work, and
anything else in it is left alone.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from bimscan.dataset.build import BuildReport

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
_TEMPLATE_START = _TEMPLATE.split("\n", 1)[0].encode("utf-8")  # how a demo's dataset.toml starts
DEFAULT_HEAD_DEG_PER_S = 60.0
PRESETS_SCANNED = ("exp1", "exp2", "exp3", "exp4", "exp5", "exp6")
RENDER_CONFIG = "exp3"  # the configuration pictured for each scene
# What the demo writes into OUT_DIR (``bimscan.files`` output folder names).
DEMO_OUTPUTS = ("dataset.toml", "dataset/", "stats/", "pictures/")


def is_earlier_demo(folder: Path) -> bool:
    """Whether ``folder`` holds a demo run before output folders had records (its dataset.toml)."""
    from bimscan.files import file_head

    return file_head(folder / "dataset.toml", len(_TEMPLATE_START)) == _TEMPLATE_START


def is_earlier_demo_pictures(folder: Path) -> bool:
    """Whether ``folder`` is the pictures folder of such a demo."""
    return is_earlier_demo(folder.parent)


def demo_spec(*, head_deg_per_s: float = DEFAULT_HEAD_DEG_PER_S) -> str:
    """The demo's dataset spec (TOML text) at a head speed in deg/s (faster: fewer points).
    ScannerSettingsError for a head speed no preset can take (``ScanSettings`` refuses it, as
    ``bimscan scan`` and ``bimscan build`` do)."""
    from bimscan.scan.device import PRESETS, with_overrides

    for preset in PRESETS_SCANNED:
        with_overrides(PRESETS[preset], head_deg_per_s=head_deg_per_s)
    ratio = 10.0 / head_deg_per_s  # the presets turn at 10 deg/s
    share = f"1/{1 / ratio:g}" if ratio < 1 else f"{ratio:g} times"
    head = repr(float(head_deg_per_s))
    configs = "\n".join(f'[[configs]]\nname = "{p}"\npreset = "{p}"\nhead_deg_per_s = {head}\n'
                         for p in PRESETS_SCANNED)
    return _TEMPLATE.replace("{head}", head).replace("{ratio}", share) + configs


def picture_names() -> list[str]:
    """The pictures the demo draws into OUT_DIR/pictures: per scene its cloud and its model beside it."""
    import tomllib

    scenes = [scene["name"] for scene in tomllib.loads(demo_spec())["scenes"]]
    return [name for scene in scenes for name in (f"{scene}_{RENDER_CONFIG}.png", f"{scene}_model_and_scan.png")]


def write_demo_spec(path: Path, *, head_deg_per_s: float = DEFAULT_HEAD_DEG_PER_S) -> Path:
    """Write the demo's dataset spec to ``path`` (atomically); returns the path."""
    from bimscan.files import write_atomic

    write_atomic(path, demo_spec(head_deg_per_s=head_deg_per_s).encode("utf-8"))
    return path


@dataclass(frozen=True)
class DemoResult:
    """What ``run_demo`` made: the spec, the dataset's build report, the statistics report (None
    when no unit finished) and the pictures."""

    spec: Path
    dataset: Path
    build: BuildReport
    stats_report: Path | None
    pictures: list[Path] = field(default_factory=list)


def run_demo(out_dir: str | Path, *, workers: int | None = None, executor: str = "local",
             head_deg_per_s: float = DEFAULT_HEAD_DEG_PER_S, log: Callable[[str], None] = lambda line: None) -> DemoResult:
    """The demo in ``out_dir``: spec, dataset (``out_dir/dataset``), statistics and pictures.

    Statistics and pictures are made for the units that finished even when others failed (the
    build report says which). ``log`` receives progress lines.
    """
    from bimscan.dataset.build import build_dataset
    from bimscan.dataset.layout import DatasetFolder, unit_id
    from bimscan.dataset.spec import device_warnings, load_spec
    from bimscan.files import check_output_folder, prepare_output_folder
    from bimscan.pipeline import load_scene
    from bimscan.render.cloud import render_cloud
    from bimscan.render.figure import render_figure
    from bimscan.stats.report import STATS_FILES, is_earlier_stats, write_stats

    demo_spec(head_deg_per_s=head_deg_per_s)  # an impossible head speed is refused before anything is made
    out = prepare_output_folder(out_dir, names=DEMO_OUTPUTS, made_by=is_earlier_demo)
    DatasetFolder(out / "dataset").prepare()  # its own folder and record, checked before any work
    check_output_folder(out / "stats", names=STATS_FILES, made_by=is_earlier_stats)
    check_output_folder(out / "pictures", names=picture_names(), made_by=is_earlier_demo_pictures)
    spec_path = write_demo_spec(out / "dataset.toml", head_deg_per_s=head_deg_per_s)
    spec = load_spec(spec_path)
    folder = DatasetFolder(out / "dataset")
    log(f"building {len(spec.scenes)} scenes x {len(spec.configs)} configurations into {folder.root}")
    warnings = device_warnings(spec)
    if warnings:
        log(f"note: {len(warnings)} settings of the paper's presets lie outside the scanner's limits, as in "
            f"the paper (`bimscan build {spec_path} ...` lists them)")
    report = build_dataset(spec, folder.root, workers=workers, executor=executor, log=log)
    done = {e.id: e for e in folder.read_manifest().done()}
    stats_report = write_stats(folder.root, out / "stats").out_dir / "report.md" if done else None
    pictures: list[Path] = []
    prepare_output_folder(out / "pictures", names=picture_names(), made_by=is_earlier_demo_pictures)
    for scene in spec.scenes:
        entry = done.get(unit_id(scene.name, RENDER_CONFIG))
        if entry is None:
            continue
        cloud = entry.cloud_file(folder.root)
        pictures.append(render_cloud(cloud, out / "pictures" / f"{scene.name}_{RENDER_CONFIG}.png").path)
        model = load_scene(folder.generated_scene_path(scene.name), scheme=spec.scheme)
        pictures.append(render_figure(model.mesh, model.components.label, model.scheme, cloud,
                                      out / "pictures" / f"{scene.name}_model_and_scan.png",
                                      model_name=f"{scene.name} (generated)").path)
    return DemoResult(spec=spec_path, dataset=folder.root, build=report, stats_report=stats_report, pictures=pictures)

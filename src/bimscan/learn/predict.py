"""Label every point of a scan with a trained network and write it as a cloud (class in
``classification`` for LAS/LAZ), streamed: labels go to a disk-backed array while blocks are
voted on, then the input is copied with them (:func:`bimscan.io.write_labelled_copy`: in its own
format with everything it holds, else through the target format's writer)."""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from bimscan.errors import LearnError
from bimscan.files import work_folder
from bimscan.learn.checkpoint import load_trained_models
from bimscan.learn.data import CHUNK_POINTS, SceneSource, check_scene_unit, list_scenes
from bimscan.learn.infer import label_scene
from bimscan.learn.model import pick_device
from bimscan.learn.train_config import EvalConfig
from bimscan.semantics import DEFAULT_SCHEME, load_scheme
from bimscan.types import CloudHeader, LabelClass, LabelScheme

if TYPE_CHECKING:
    from bimscan.io import LabelledCopyPlan

# Tableau 10 (the palette of the built-in spc5 scheme) for classes the default scheme does not
# name; the default scheme's classes keep its colours, as in bimscan's synthetic clouds
PALETTE = ("#4e79a7", "#f28e2b", "#e15759", "#76b7b2", "#59a14f", "#edc948", "#b07aa1", "#ff9da7", "#9c755f", "#bab0ac")
CLASS_COLORS = {c.name: c.color for c in load_scheme(DEFAULT_SCHEME).classes}


@dataclass(frozen=True)
class PredictionResult:
    """Where the labelled cloud went and what it holds: class_counts (C,) int64."""

    path: Path
    points: int
    class_counts: np.ndarray
    class_names: tuple[str, ...]
    nearest_filled: int
    seconds: float
    network_points: int = 0


def build_prediction_scheme(class_names: tuple[str, ...], stored: LabelScheme | None = None) -> LabelScheme:
    """The label scheme stored with predicted clouds: the checkpoint's classes.

    The input cloud's own scheme (``stored``) is kept when it lists the same classes in the
    same order (its colours and rules stay meaningful); otherwise a rule-less scheme is made.
    """
    if stored is not None and tuple(c.name for c in sorted(stored.classes, key=lambda c: c.id)) == class_names \
            and [c.id for c in sorted(stored.classes, key=lambda c: c.id)] == list(range(len(class_names))):
        return stored
    classes = tuple(
        LabelClass(id=i, name=name, color=CLASS_COLORS.get(name, PALETTE[i % len(PALETTE)]))
        for i, name in enumerate(class_names)
    )
    return LabelScheme(name="pct-prediction", classes=classes, rules=(), default_label=class_names[-1])


def check_prediction_output(
    in_path: str | Path, out_path: str | Path, *, overwrite: bool = False, top_class: int = 0,
) -> LabelledCopyPlan:
    """How ``predict_cloud`` will write ``out_path`` from the scan ``in_path`` (one cloud, a dataset
    unit's folder included), checked before any work: see ``bimscan.io.plan_labelled_copy``
    (``top_class``: the highest class id the labels take)."""
    from bimscan.io import plan_labelled_copy

    sources = list_scenes([in_path])
    if len(sources) != 1:
        raise LearnError(f"{in_path}: holds {len(sources)} scenes; predict one cloud at a time")
    return plan_labelled_copy(sources[0].path, out_path, overwrite=overwrite, top_class=top_class)


def predict_cloud(
    checkpoint: str | Path, in_path: str | Path, out_path: str | Path, *, device: str = "auto",
    evaluation: EvalConfig | None = None, overwrite: bool = False, chunk_points: int = CHUNK_POINTS, warn: Callable[[str], None] | None = None,
    ensemble: Sequence[str | Path] = (),
) -> PredictionResult:
    """Label every point of ``in_path`` and write ``out_path`` (format by suffix, see bimscan.io).

    The output is a labelled copy of the input (``bimscan.io.write_labelled_copy``): in the
    input's own format (LAS <-> LAZ included) it keeps everything the input holds (a LAS's header,
    scales, offsets, CRS and other VLRs/EVLRs, extra dimensions and point records; a PLY's every
    property and element; every column of a text cloud; every array of a NumPy folder; an E57's
    scans, poses and point fields) with only the class changed; in another format it keeps the
    columns and every per-point field that format holds (extra dimensions, normals, scalar
    fields, ...), and ``warn`` receives one line naming what it does not (a CRS in a PLY, ...).
    The input's own labels are replaced (they are neither read for use nor checked).
    ``ensemble``: more checkpoints whose class probabilities are averaged with the checkpoint's.

    ``out_path`` is checked before any work (the input's columns too: E57 cannot hold a mobile
    scan's); an output that is the input itself is refused unless the copy keeps all of it, and
    is then replaced only at the end, once written whole. Nothing is left at it when anything
    fails. The work files go to a hidden folder beside ``out_path``
    (``bimscan.files.work_folder``), removed at the end, or by the next run when this one is killed.
    """
    from bimscan.io import read_cloud_header, write_labelled_copy

    out_path = Path(out_path)
    check_prediction_output(in_path, out_path, overwrite=overwrite)  # before the checkpoint is read
    source: SceneSource = list_scenes([in_path])[0]
    torch_device = pick_device(device)
    trained = load_trained_models([checkpoint, *ensemble], device=torch_device,
                                  weights=None if evaluation is None else evaluation.weights)
    evaluation = (evaluation or trained.config.eval).with_seed(trained.config.train.seed)
    evaluation.stride_for(trained.config.blocks.size_m)  # a stride that does not divide the blocks: one line now
    check_scene_unit(source, blocks=trained.config.blocks)  # a scan in millimetres: one line now
    plan = check_prediction_output(in_path, out_path, overwrite=overwrite, top_class=len(trained.class_names) - 1)
    for line in plan.notices():
        (warn or _warn)(line)
    with work_folder(out_path) as folder:
        index_file, label_file = folder / "index.i8", folder / "label.u1"
        with index_file.open("wb") as index_out, label_file.open("wb") as label_out:

            def keep(index: np.ndarray, prediction: np.ndarray) -> None:
                # labels arrive stripe by stripe, in no point order: log them to disk
                index.astype(np.int64).tofile(index_out)
                prediction.astype(np.uint8).tofile(label_out)

            result = label_scene(
                trained.model, source, class_names=trained.class_names, blocks=trained.config.blocks,
                evaluation=evaluation, device=torch_device, amp=trained.config.train.amp, use_labels=False, work_dir=folder, on_labels=keep, chunk_points=chunk_points,
                inputs=trained.config.input, warn=warn, checkpoint=checkpoint,
            )
        labels = np.memmap(folder / "labels.u1", dtype=np.uint8, mode="w+", shape=(result.points,))
        counts = np.zeros(len(trained.class_names), dtype=np.int64)
        for offset in range(0, result.points, chunk_points):
            count = min(chunk_points, result.points - offset)
            index = np.fromfile(index_file, dtype=np.int64, count=count, offset=offset * 8)
            labels[index] = np.fromfile(label_file, dtype=np.uint8, count=count, offset=offset)
        for offset in range(0, result.points, chunk_points):
            counts += np.bincount(labels[offset:offset + chunk_points], minlength=len(counts))[: len(counts)]
        stored = read_cloud_header(source.path)
        centre = np.round((result.lower + result.upper) / 2.0)
        header = CloudHeader(
            scheme=build_prediction_scheme(trained.class_names, None if stored is None else stored.scheme),
            components=None if stored is None else stored.components,
            stations=() if stored is None else stored.stations,
            origin=tuple(float(v) for v in (centre if stored is None else stored.origin)),  # type: ignore[arg-type]
            metadata={
                "prediction": {
                    "checkpoint": str(checkpoint), "epoch": trained.epoch, "weights": trained.weights,
                    **({"ensemble": [str(p) for p in ensemble]} if ensemble else {}),
                    "source": str(in_path), "seed": evaluation.seed, "max_passes": evaluation.max_passes,
                    "block_size_m": trained.config.blocks.size_m, "points_per_block": trained.config.blocks.points,
                    "evaluation": asdict(evaluation),
                },
                **({} if stored is None else {"source_metadata": dict(stored.metadata)}),
            },
        )
        write_labelled_copy(plan, labels, header=header)
        del labels  # release the memory map before the folder goes
    return PredictionResult(
        path=out_path, points=result.points, class_counts=counts, class_names=trained.class_names,
        nearest_filled=result.nearest_filled, seconds=result.seconds, network_points=result.network_points,
    )


def _warn(line: str) -> None:
    warnings.warn(line, stacklevel=3)

"""A mobile platform's path: its pose over time, read from or written to CSV.

A ``Trajectory`` holds samples of the platform's pose (``survey.platform``: origin on the floor
under the operator, x along the walk): time ``t`` (seconds), position ``xyz`` (world metres) and
``roll``, ``pitch``, ``yaw`` (radians; body -> world rotation Rz(yaw) Ry(pitch) Rx(roll), yaw
counter-clockwise from +x). Poses between samples are interpolated linearly (yaw unwrapped). A
trajectory may hold several *passes* (``pass_id``): separate walks of one survey, each a
contiguous run of samples (a planned walk makes one per part of a building that cannot be
walked to from another); the scanner fires only while a pass runs.

CSV (``read_trajectory``, ``write_trajectory``): a header line and the columns
``t,x,y,z,roll,pitch,yaw`` (HELIOS++'s interpolated-trajectory columns; angles in degrees) and
optionally ``pass``. Lines starting with ``#`` are comments.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bimscan.errors import InputFileError
from bimscan.files import check_input_file, write_atomic

TRAJECTORY_COLUMNS = ("t", "x", "y", "z", "roll", "pitch", "yaw")
MAX_TRAJECTORY_SECONDS = 6 * 3600.0  # a longer walk is most likely a unit mistake (milliseconds)


@dataclass(frozen=True, eq=False)
class Trajectory:
    """Platform poses over time (see the module docs). t (K,) float64 strictly increasing within a
    pass; xyz (K, 3) float64; roll, pitch, yaw (K,) float64 radians; pass_id (K,) int32,
    non-decreasing, 0-based and contiguous. closures: (M,) float64 times where the walk comes back
    to a place it was before (loop closures of a SLAM solution; ``survey.drift``)."""

    t: np.ndarray
    xyz: np.ndarray
    roll: np.ndarray
    pitch: np.ndarray
    yaw: np.ndarray
    pass_id: np.ndarray
    closures: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def __post_init__(self) -> None:
        k = len(self.t)
        if k < 2 or self.xyz.shape != (k, 3) or not all(len(a) == k for a in (self.roll, self.pitch, self.yaw,
                                                                                 self.pass_id)):
            raise InputFileError(f"a trajectory needs at least 2 samples with every column, got {k}")
        values = np.column_stack([self.t, self.xyz, self.roll, self.pitch, self.yaw])
        if not np.isfinite(values).all():
            raise InputFileError("a trajectory holds a value that is not a finite number; fix the trajectory")
        if np.any(np.diff(self.pass_id) < 0) or np.any(np.diff(self.pass_id) > 1) or self.pass_id[0] != 0:
            raise InputFileError("trajectory passes must be numbered 0, 1, 2, ... in the order of their samples")
        same = np.diff(self.pass_id) == 0
        if np.any(np.diff(self.t)[same] <= 0) or np.any(np.diff(self.t) <= 0):
            bad = int(np.flatnonzero(np.diff(self.t) <= 0)[0]) + 1
            raise InputFileError(f"trajectory time must increase from sample to sample; sample {bad} "
                                 f"(t = {self.t[bad]:g} s) does not")
        if self.t[-1] - self.t[0] > MAX_TRAJECTORY_SECONDS:
            raise InputFileError(f"the trajectory lasts {self.t[-1] - self.t[0]:.3g} s, more than "
                                 f"{MAX_TRAJECTORY_SECONDS / 3600:g} hours; give t in seconds")
        for pass_index in range(self.n_passes):
            if int(np.count_nonzero(self.pass_id == pass_index)) < 2:
                raise InputFileError(f"trajectory pass {pass_index} has fewer than 2 samples")

    @property
    def n_passes(self) -> int:
        return int(self.pass_id[-1]) + 1

    def pass_slices(self) -> list[slice]:
        """The sample range of each pass."""
        edges = np.flatnonzero(np.diff(self.pass_id)) + 1
        bounds = [0, *edges.tolist(), len(self.t)]
        return [slice(a, b) for a, b in zip(bounds[:-1], bounds[1:])]

    def ypr(self, part: slice = slice(None)) -> np.ndarray:
        """(K, 3) yaw (unwrapped), pitch, roll in radians: what the ray kernel interpolates."""
        return np.ascontiguousarray(np.column_stack([np.unwrap(self.yaw[part]), self.pitch[part], self.roll[part]]))

    def length_m(self) -> float:
        """Metres walked (within passes)."""
        steps = np.linalg.norm(np.diff(self.xyz, axis=0), axis=1)
        return float(steps[np.diff(self.pass_id) == 0].sum())

    def duration_s(self) -> float:
        """Seconds the passes last together."""
        return float(sum(self.t[p][-1] - self.t[p][0] for p in self.pass_slices()))

    def position_at(self, t: np.ndarray) -> np.ndarray:
        """(N, 3) the platform origin at times t (linear between samples; clamped to the ends)."""
        return np.column_stack([np.interp(t, self.t, self.xyz[:, axis]) for axis in range(3)])


def read_trajectory(path: str | Path) -> Trajectory:
    """A trajectory CSV (see the module docs) -> Trajectory; one-line errors for bad files."""
    path = check_input_file(path, what="a trajectory CSV file (t,x,y,z,roll,pitch,yaw)")
    try:
        text = path.read_text("utf-8-sig")  # a byte order mark (spreadsheet exports) is not part of the header
    except UnicodeDecodeError as exc:
        raise InputFileError(f"{path}: not a UTF-8 text file; pass a trajectory CSV file") from exc
    lines = [line for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")]
    rows = list(csv.reader(lines))
    if not rows:
        raise InputFileError(f"{path}: empty; give a header line t,x,y,z,roll,pitch,yaw and one line per pose")
    header = [c.strip().lower() for c in rows[0]]
    missing = [c for c in TRAJECTORY_COLUMNS if c not in header]
    if missing:
        raise InputFileError(f"{path}: the header lacks column(s) {', '.join(missing)}; the first line must name "
                             "t,x,y,z,roll,pitch,yaw (angles in degrees), optionally pass")
    index = [header.index(c) for c in TRAJECTORY_COLUMNS]
    pass_index = header.index("pass") if "pass" in header else None
    values, passes = [], []
    for number, row in enumerate(rows[1:], start=2):
        try:
            values.append([float(row[i]) for i in index])
            passes.append(int(row[pass_index]) if pass_index is not None else 0)
        except (ValueError, IndexError) as exc:
            raise InputFileError(f"{path}: data line {number} ({','.join(row)!r}) is not a row of numbers under the "
                                 "header; fix or remove it") from exc
    if len(values) < 2:
        raise InputFileError(f"{path}: a trajectory needs at least 2 poses, got {len(values)}")
    data = np.asarray(values, dtype=np.float64)
    try:
        return Trajectory(t=data[:, 0], xyz=data[:, 1:4], roll=np.radians(data[:, 4]), pitch=np.radians(data[:, 5]),
                          yaw=np.radians(data[:, 6]), pass_id=np.asarray(passes, dtype=np.int32))
    except InputFileError as exc:
        raise InputFileError(f"{path}: {exc}") from exc


def trajectory_csv(trajectory: Trajectory) -> bytes:
    """The CSV bytes of a trajectory (angles in degrees, 6 decimals: micrometres and microseconds)."""
    out = io.StringIO()
    out.write("t,x,y,z,roll,pitch,yaw,pass\n")
    degrees = np.degrees(np.column_stack([trajectory.roll, trajectory.pitch, trajectory.yaw]))
    for k in range(len(trajectory.t)):
        x, y, z = trajectory.xyz[k]
        roll, pitch, yaw = degrees[k]
        out.write(f"{trajectory.t[k]:.6f},{x:.6f},{y:.6f},{z:.6f},{roll:.6f},{pitch:.6f},{yaw:.6f},"
                  f"{int(trajectory.pass_id[k])}\n")
    return out.getvalue().replace("-0.000000", "0.000000").encode("ascii")


def write_trajectory(path: str | Path, trajectory: Trajectory) -> Path:
    """Write the trajectory CSV atomically (the file appears complete or not at all)."""
    path = Path(path)
    write_atomic(path, trajectory_csv(trajectory))
    return path


def trajectory_path(cloud: str | Path) -> Path:
    """Where a mobile scan's trajectory goes: beside the cloud, ``OUT.trajectory.csv``."""
    cloud = Path(str(cloud).rstrip("/"))
    return cloud.with_name(cloud.name + ".trajectory.csv")

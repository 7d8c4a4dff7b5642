"""One streamed pass over a scan: its points thinned to voxel centroids, its extent, and the
stations it was scanned from.

Alignment works on the centroids of the scan's points in cubes of ``voxel_m`` (the voxel grid
filter every registration tool applies first): the same surfaces, evenly dense whatever the
distance to the scanner, and a few hundred thousand points however many the file holds. The
cubes are counted in chunks and merged as they come, so memory follows the scanned surface,
not the point count. Coordinates are kept relative to an ``anchor`` near the first points
(whole metres), so a scan in map coordinates (a UTM northing of 5,400 km) keeps its
millimetres in float64 arithmetic and float32 engines.

Stations: a bimscan cloud's header lists them with their positions, an E57 file poses each of
its scans; another tool's cloud may carry station ids without positions (LAS point source ids),
or nothing.

Viewers: each centroid keeps where its points were seen from, roughly, so that alignment can
tell the two faces of a wall apart (a scanner sees the face turned towards it): a walk's beam
origins (their mean per cube), a station's recorded position, or for station ids without
positions the mean of that station's points (a tripod's points surround it: their mean lies in
the room it stood in). NaN where the file says nothing of its stations.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numba as nb
import numpy as np

from bimscan.errors import CompareError, number
from bimscan.types import PointCloud

CHUNK_POINTS = 2_000_000
_KEY_BITS = 21  # voxel indices per axis in a packed key: +-2^20 voxels around the anchor
_KEY_LIMIT = 1 << (_KEY_BITS - 1)


@dataclass(frozen=True)
class ScanStation:
    """A station of the scan: its id in the cloud, its beam origin in the scan's frame (metres;
    None when the file does not say) and how many points it holds."""

    id: int
    position: tuple[float, float, float] | None
    points: int


@dataclass(frozen=True)
class ScanDigest:
    """What one pass over a scan keeps.

    anchor: (3,) float64 scan-frame metres, the origin of ``xyz``; xyz: (V, 3) float64 voxel
    centroids relative to the anchor; weight: (V,) int64 points per voxel; lower, upper: (3,)
    float64 the scan's bounds (scan frame, absolute); stations: the stations found; columns: the
    cloud's columns (``PointCloud.COLUMNS`` names).
    """

    path: Path
    points: int
    anchor: np.ndarray
    voxel_m: float
    xyz: np.ndarray
    weight: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    stations: tuple[ScanStation, ...]
    columns: frozenset[str]
    viewer: np.ndarray | None = None

    def __len__(self) -> int:
        return int(len(self.xyz))


class VoxelCentroids:
    """Running sums of points per voxel, merged in batches (memory: the occupied voxels)."""

    def __init__(self, anchor: np.ndarray, voxel_m: float) -> None:
        self.anchor = np.asarray(anchor, dtype=np.float64)
        self.voxel_m = float(voxel_m)
        self._parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self._pending = 0
        self._merged = 0

    def add(self, xyz: np.ndarray, extra: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Add points (N, 3) float64 in the scan's frame (absolute), with ``extra`` (N, K) float64
        columns summed per voxel beside them (the same K for every call). Returns the points'
        bounds (lower (3,), upper (3,))."""
        extra = np.zeros((len(xyz), 0)) if extra is None else np.ascontiguousarray(extra, dtype=np.float64)
        key, sums, lower, upper, far = _voxel_sums(np.ascontiguousarray(xyz, dtype=np.float64), extra, self.anchor,
                                                    self.voxel_m, _KEY_LIMIT, _KEY_BITS)
        if far > 0:
            raise CompareError(
                f"the scan reaches {number(far / 1000, 1)} km from its first points; a building scan spans less "
                f"than {number(_KEY_LIMIT * self.voxel_m / 1000, 1)} km: check the file's coordinates and units")
        self._push(*_reduce(key, sums, np.ones(len(key), dtype=np.int64)))
        return lower, upper

    def _push(self, key: np.ndarray, sums: np.ndarray, count: np.ndarray) -> None:
        self._parts.append((key, sums, count))
        self._pending += len(key)
        if self._pending > max(4_000_000, 2 * self._merged):
            self._merge()

    def _merge(self) -> None:
        if len(self._parts) > 1:
            key = np.concatenate([p[0] for p in self._parts])
            sums = np.concatenate([p[1] for p in self._parts])
            count = np.concatenate([p[2] for p in self._parts])
            self._parts = [_reduce(key, sums, count)]
        self._merged = self._pending = len(self._parts[0][0]) if self._parts else 0

    def result(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(centroids (V, 3) float64 relative to the anchor, points per voxel (V,) int64, the extra
        columns' means (V, K)), in key order."""
        self._merge()
        if not self._parts:
            return np.zeros((0, 3)), np.zeros(0, dtype=np.int64), np.zeros((0, 0))
        key, sums, count = self._parts[0]
        order = np.argsort(key, kind="stable")  # key order: the same centroids in the same order however read
        sums, count = sums[order], count[order]
        means = sums / count[:, None]
        return means[:, :3], count, means[:, 3:]


def _reduce(key: np.ndarray, sums: np.ndarray, count: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The sums and counts of equal keys added up (keys in order of first appearance)."""
    return _hash_reduce(np.ascontiguousarray(key), np.ascontiguousarray(sums), np.ascontiguousarray(count))


@nb.njit(cache=True)
def _voxel_sums(xyz: np.ndarray, extra: np.ndarray, anchor: np.ndarray, voxel: float, limit: int,
                bits: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    """Each point's voxel key, its row of sums (xyz relative to the anchor, then ``extra``), the
    points' bounds, and the farthest distance from the anchor of a point outside the key's reach
    (0: none)."""
    n, k = xyz.shape[0], extra.shape[1]
    key = np.empty(n, dtype=np.int64)
    sums = np.empty((n, 3 + k))
    lower = np.full(3, np.inf)
    upper = np.full(3, -np.inf)
    far = 0.0
    for i in range(n):
        packed = 0
        for a in range(3):
            value = xyz[i, a]
            lower[a] = min(lower[a], value)
            upper[a] = max(upper[a], value)
            local = value - anchor[a]
            sums[i, a] = local
            index = int(np.floor(local / voxel))
            if index < -limit or index >= limit:
                far = max(far, abs(local))
                index = 0
            packed = (packed << bits) | (index + limit)
        key[i] = packed
        for c in range(k):
            sums[i, 3 + c] = extra[i, c]
    return key, sums, lower, upper, far


@nb.njit(cache=True)
def _hash_reduce(key: np.ndarray, sums: np.ndarray, count: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows of equal keys (non-negative) summed, by open addressing: one pass, no sort."""
    n = key.shape[0]
    size, shift = 16, 4
    while size < 2 * n:
        size <<= 1
        shift += 1
    mask = size - 1
    slot_key = np.full(size, -1, dtype=np.int64)
    slot_row = np.empty(size, dtype=np.int64)
    out_key = np.empty(n, dtype=np.int64)
    out_sums = np.zeros((n, sums.shape[1]))
    out_count = np.zeros(n, dtype=np.int64)
    m = 0
    last_key, last_row = -1, -1
    for i in range(n):
        k = key[i]
        if k == last_key:  # a scan's consecutive points mostly share a voxel
            for c in range(sums.shape[1]):
                out_sums[last_row, c] += sums[i, c]
            out_count[last_row] += count[i]
            continue
        h = np.int64((np.uint64(k) * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(64 - shift))  # Fibonacci hashing
        while True:
            if slot_key[h] == -1:
                slot_key[h] = k
                slot_row[h] = m
                out_key[m] = k
                row = m
                m += 1
                break
            if slot_key[h] == k:
                row = slot_row[h]
                break
            h = (h + 1) & mask
        for c in range(sums.shape[1]):
            out_sums[row, c] += sums[i, c]
        out_count[row] += count[i]
        last_key, last_row = k, row
    return out_key[:m], out_sums[:m], out_count[:m]


def station_field(scan_path: Path) -> str | None:
    """The field that holds another tool's LAS stations: registration software writes each point's
    scan position into ``point_source_id`` (bimscan's own files carry a station column)."""
    from bimscan.io import input_format, read_cloud_header

    return "point_source_id" if input_format(scan_path) in ("las", "laz") and read_cloud_header(scan_path) is None \
        else None


def scan_stations(path: str | Path) -> dict[int, tuple[float, float, float]]:
    """Station id -> beam origin (scan frame, metres) as the file records it: a bimscan cloud's
    header stations, or an E57 file's scan poses (foreign files: the scan's index); empty when
    the file records none."""
    from bimscan.io import input_format, read_cloud_header

    path = Path(path)
    header = read_cloud_header(path)
    if header is not None and header.stations:
        return {s.id: tuple(float(v) for v in s.position) for s in header.stations}  # type: ignore[misc]
    if input_format(path) == "e57":
        from bimscan.io.e57 import read_e57_scans

        scans = read_e57_scans(path)
        return {(s.station_id if s.station_id is not None else s.index): tuple(float(v) for v in s.translation)
                for s in scans}  # type: ignore[misc]
    return {}


def digest_scan(path: str | Path, *, voxel_m: float, chunk_points: int = CHUNK_POINTS,
                on_chunk: Callable[[PointCloud], None] | None = None,
                progress: Callable[[int], None] | None = None) -> ScanDigest:
    """Read ``path`` (any cloud bimscan reads) once: voxel centroids, bounds, stations.

    ``on_chunk`` sees every chunk as read (scan frame); ``progress`` gets the points read so far.
    """
    from bimscan.io import iter_cloud_chunks

    path = Path(path)
    centroids: VoxelCentroids | None = None
    lower, upper = np.full(3, np.inf), np.full(3, -np.inf)
    per_station = np.zeros(0, dtype=np.int64)
    station_sums = np.zeros((0, 3))
    columns: frozenset[str] = frozenset()
    points = 0
    walk: bool | None = None
    for chunk in iter_cloud_chunks(path, chunk_points=chunk_points, labels=False, station_field=station_field(path)):
        if not len(chunk):
            continue
        if centroids is None:
            columns = frozenset(c for c in PointCloud.COLUMNS if getattr(chunk, c) is not None)
            centroids = VoxelCentroids(np.round(np.median(chunk.xyz[:100_000], axis=0)), voxel_m)
            walk = chunk.sensor_xyz is not None
        # per voxel: the mean beam origin of a walk, or the mean station id (a whole number where one
        # station saw the voxel)
        if walk:
            extra = chunk.sensor_xyz - centroids.anchor  # type: ignore[operator]
        else:
            extra = (chunk.station if chunk.station is not None else np.full(len(chunk), -1.0)).astype(np.float64)[:, None]
        low, high = centroids.add(chunk.xyz, extra)
        lower, upper = np.minimum(lower, low), np.maximum(upper, high)
        if chunk.station is not None:
            counts = np.bincount(chunk.station)
            if len(counts) > len(per_station):
                per_station = np.pad(per_station, (0, len(counts) - len(per_station)))
                station_sums = np.pad(station_sums, ((0, len(counts) - len(station_sums)), (0, 0)))
            per_station[: len(counts)] += counts
            local = chunk.xyz - centroids.anchor
            for axis in range(3):
                station_sums[: len(counts), axis] += np.bincount(chunk.station, weights=local[:, axis],
                                                                 minlength=len(counts))
        if on_chunk is not None:
            on_chunk(chunk)
        points += len(chunk)
        if progress is not None:
            progress(points)
    if centroids is None:
        raise CompareError(f"{path}: holds no points; pass a scan with points")
    xyz, weight, extra = centroids.result()
    known = scan_stations(path)
    stations = tuple(ScanStation(id=int(i), position=known.get(int(i)), points=int(per_station[i]))
                     for i in np.flatnonzero(per_station))
    if walk:
        viewer = extra
    else:
        viewer = np.full((len(xyz), 3), np.nan)
        mean = extra[:, 0]
        one = (mean >= 0) & (np.abs(mean - np.round(mean)) < 1e-6)  # one station's voxels (mostly; a few
        # shared by stations whose ids average to a whole number take that station's side: a rough viewer)
        ids = np.round(mean[one]).astype(np.int64)
        place = np.full((len(per_station), 3), np.nan)
        for i in np.flatnonzero(per_station):
            recorded = known.get(int(i))
            place[i] = (np.asarray(recorded) - centroids.anchor) if recorded is not None \
                else station_sums[i] / per_station[i]
        if len(place):
            viewer[one] = place[ids]
    return ScanDigest(path=path, points=points, anchor=centroids.anchor, voxel_m=float(voxel_m), xyz=xyz,
                      weight=weight, lower=lower, upper=upper, stations=stations, columns=columns, viewer=viewer)

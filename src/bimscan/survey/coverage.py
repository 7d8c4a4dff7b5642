"""How well a scan from outside covers a building's outer surface, element by element (the check of
a drone's flight: every roof and facade element seen at a density, or listed with why not).

The outer surface: the model's triangles (the ground and the site's objects left out) sampled as
the survey planner samples them (``planning.surface.sample_surfaces``, one sample per
``SAMPLE_M`` squared, seeded); a sample is outer when a ray leaving it along its face's normal
(either side: a face's winding does not matter), or tilted ``OPEN_TILT_DEG`` from it towards any
of four sides, escapes the building (meets nothing): so a facade under an overhang still counts, a face against another
element or inside the building does not. A sample is covered when the scan's points within
``radius_m`` of it give at least ``density_per_m2`` points per square metre (count / (pi r^2)).
An element's coverage is the covered share of its outer samples' area; elements with fewer than
``MIN_OUTER_SAMPLES`` outer samples are too small to judge and left out. ``bimscan coverage``
writes the table (``coverage_csv``).
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from bimscan.scan.probe import Prober
from bimscan.site.classes import SITE_CLASSES
from bimscan.survey.flight import ground_level
from bimscan.survey.planning.surface import SurfaceSamples, sample_surfaces
from bimscan.types import BimScene, SceneMesh

SAMPLE_M = 0.25
DENSITY_PER_M2 = 100.0
RADIUS_M = 0.15
COVERED_SHARE = 0.8  # an element is covered when this share of its outer surface is
OPEN_TILT_DEG = 60.0
MIN_OUTER_SAMPLES = 4
ESCAPE_OFFSET_M = 1e-3


@dataclass(frozen=True)
class ElementCoverage:
    """One element's outer surface and how much of it the scan covers (``covered_share`` in [0, 1]);
    ``facing``: where most of its outer surface faces (``up``, ``side`` or ``down``); ``buried``: the
    share of its outer surface below the ground (``Terrain.Ground``), which no scan from outside sees."""

    component: int
    global_id: str
    ifc_class: str
    name: str
    outer_m2: float
    covered_share: float
    facing: str
    buried: float = 0.0

    def why_not(self) -> str:
        """Why a poorly covered element is: below the ground, facing down (a soffit), or not reached."""
        if self.buried > 0.5:
            return "below the ground"
        if self.facing == "down":
            return "faces down (a soffit, seen from below only)"
        return "not reached at the density by the scan's poses"


def outer_samples(scene: BimScene, *, sample_m: float = SAMPLE_M, seed: int = 0,
                  threads: int = 0) -> tuple[SurfaceSamples, np.ndarray]:
    """Samples of the building's outer surface (see the module docs): the planner's surface samples
    (``planning.surface.sample_surfaces``, one per ``sample_m`` squared) that are outer, and (S, 3)
    their outward unit normals (the side whose rays escape: faces wound either way are judged alike)."""
    table, mesh = scene.components, scene.mesh
    building = ~np.isin(table.ifc_class, list(SITE_CLASSES))
    samples = sample_surfaces(mesh, building, samples_per_m2=1.0 / sample_m**2, min_samples=1, seed=seed)
    faces_kept = building[mesh.face_component]
    prober = Prober(SceneMesh(vertices=mesh.vertices, faces=mesh.faces[faces_kept],
                              face_component=mesh.face_component[faces_kept]), threads=threads)
    outward = samples.normal.copy()
    outer = np.zeros(len(samples), dtype=bool)
    for side in (1.0, -1.0):
        for direction in _open_directions(side * samples.normal):
            remaining = np.flatnonzero(~outer)
            if len(remaining) == 0:
                break
            t, _ = prober.cast(samples.xyz[remaining] + ESCAPE_OFFSET_M * direction[remaining], direction[remaining])
            escaped = remaining[~np.isfinite(t)]
            outer[escaped] = True
            outward[escaped] = side * samples.normal[escaped]
    return samples.take(np.flatnonzero(outer)), outward[outer]


def _open_directions(normals: np.ndarray) -> list[np.ndarray]:
    """The normal, then the normal tilted ``OPEN_TILT_DEG`` towards four sides (unit vectors)."""
    helper = np.where(np.abs(normals[:, 2:3]) < 0.9, np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 0.0, 0.0]]))
    a = np.cross(normals, helper)
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b = np.cross(normals, a)
    c, s = math.cos(math.radians(OPEN_TILT_DEG)), math.sin(math.radians(OPEN_TILT_DEG))
    return [normals] + [c * normals + s * side for side in (a, -a, b, -b)]


def element_coverage(scene: BimScene, chunks: Iterable[np.ndarray], *, density_per_m2: float = DENSITY_PER_M2,
                     radius_m: float = RADIUS_M, sample_m: float = SAMPLE_M, threads: int = 0) -> list[ElementCoverage]:
    """Each outer element's covered share (see the module docs) by a scan's points, given as chunks of
    (N, 3) world metres (one array, or a stream: the counts add up chunk by chunk, so memory stays
    that of one chunk), sorted by share (least covered first)."""
    samples, normals = outer_samples(scene, sample_m=sample_m, threads=threads)
    xyz, component, area = samples.xyz, samples.component, samples.area_m2
    near = np.zeros(len(xyz), dtype=np.int64)
    for points in ([chunks] if isinstance(chunks, np.ndarray) else chunks):
        if len(points):
            near += cKDTree(np.asarray(points, dtype=np.float64)).query_ball_point(
                xyz, radius_m, return_length=True, workers=-1)
    covered = near / (math.pi * radius_m**2) >= density_per_m2
    table = scene.components
    terrain = np.flatnonzero(table.ifc_class == "Terrain.Ground")
    if len(terrain):
        ground_z = float(np.median(scene.mesh.vertices[scene.mesh.faces[scene.mesh.face_component == terrain[0]], 2]))
    else:  # the model without its dressing: where a drone's ground would lie
        ground_z = ground_level(float(scene.mesh.vertices[:, 2].min()), tuple(s.elevation_m for s in scene.storeys))
    out = []
    for c in np.unique(component):
        mine = component == c
        if mine.sum() < MIN_OUTER_SAMPLES:
            continue
        nz = float(np.median(normals[mine, 2]))
        facing = "up" if nz > 0.5 else "down" if nz < -0.5 else "side"
        out.append(ElementCoverage(component=int(c), global_id=str(table.global_id[c]), ifc_class=str(table.ifc_class[c]),
                                   name=str(table.name[c]), outer_m2=float(area[mine].sum()),
                                   covered_share=float(np.average(covered[mine], weights=area[mine])), facing=facing,
                                   buried=float(np.average(xyz[mine, 2] < ground_z, weights=area[mine]))))
    return sorted(out, key=lambda e: (e.covered_share, e.global_id))


def coverage_csv(elements: Sequence[ElementCoverage], *, share: float) -> bytes:
    """The elements as CSV: GlobalId, IFC class, name, facing, outer area, covered share, share below
    the ground, and whether it is covered (at ``share``) or why not."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(["global_id", "ifc_class", "name", "facing", "outer_m2", "covered_share", "below_ground_share",
                     "status"])
    for e in elements:
        writer.writerow([e.global_id, e.ifc_class, e.name, e.facing, f"{e.outer_m2:.2f}", f"{e.covered_share:.4f}",
                         f"{e.buried:.4f}", "covered" if e.covered_share >= share else e.why_not()])
    return out.getvalue().encode("utf-8")

"""Pictures of a survey plan, one per storey: where the stations stand, the order to scan them,
the registration graph, and how well each part of the surface is covered.

Two plan views side by side: the walls and the floor (upright surfaces and those near the
storey's floor), and the ceiling (level surfaces higher up, seen from below). Every surface
sample is a dot coloured by its state: covered at the asked density, short of it, seen only
more edge-on than the incidence limit, or never seen from any tripod spot. Elements short of the
asked coverage are marked with a red cross and their covered share; stations are numbered in scan
order (their ids, as in the station file and the scan's station column), joined by arrows in
that order and by grey lines where they register to each other.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from bimscan.files import save_png

if TYPE_CHECKING:
    from bimscan.survey.planning.plan import PlanEvaluation, SurveyPlan

STATE_COLORS = {"covered": "#2ca02c", "short of the density": "#ff7f0e",
                "seen only edge-on": "#9467bd", "never seen": "#c7c7c7"}
DRAW_ORDER = np.array([1, 3, 2, 0])  # by state index: covered, short, edge-on, never seen
CEILING_ABOVE_FLOOR_M = 1.0  # level surfaces higher than this over the storey's floor are ceilings
MAX_DOTS = 200_000  # per panel: a picture is for the eye


def sample_states(plan: SurveyPlan, evaluation: PlanEvaluation) -> np.ndarray:
    """(S,) int index into ``STATE_COLORS`` of every surface sample."""
    space = plan.space
    reachable, seen = space.visibility.reachable, space.visibility.seen
    covered = reachable & (evaluation.density >= space.config.density_pts_m2)
    state = np.full(len(reachable), 3, dtype=np.int64)
    state[seen & ~reachable] = 2
    state[reachable] = 1
    state[covered] = 0
    return state


def storey_slug(index: int, name: str) -> str:
    """A file name for a storey's picture: ``plan_<n>_<name as ASCII letters, digits and dashes>.png``."""
    text = re.sub(r"[^A-Za-z0-9]+", "-", name).strip("-")[:40]
    return f"plan_{index}{'_' + text if text else ''}.png"


def draw_plan_pictures(plan: SurveyPlan, evaluation: PlanEvaluation, folder: Path, *, title: str) -> list[str]:
    """Write one PNG per storey that holds stations or sampled surface into ``folder``; returns
    their file names, lowest storey first (see ``storey_bands``); stations go by their storey,
    else by their floor height."""
    space = plan.space
    samples = space.samples
    storeys = sorted(space.scene.storeys, key=lambda s: s.elevation_m)
    elevations = np.array([s.elevation_m for s in storeys] or [float(samples.xyz[:, 2].min()) if len(samples) else 0.0])
    names = [s.name for s in storeys] or [""]
    band, ceiling = storey_bands(samples.xyz[:, 2], samples.normal[:, 2], elevations)
    states = sample_states(plan, evaluation)
    lo, hi = (samples.xyz.min(axis=0), samples.xyz.max(axis=0)) if len(samples) else (np.zeros(3), np.ones(3))
    floor_band, _ = storey_bands(np.array([s.floor_z if s.floor_z is not None else s.position[2] - 1.7
                                           for s in plan.stations]), np.zeros(len(plan.stations)), elevations)
    written = []
    for index, name in enumerate(names):
        stations = [s for s, b in zip(plan.stations, floor_band)
                    if (s.storey == name if s.storey in names else b == index)]
        mine = (band == index) & (space.klass >= 0)  # the classes to cover
        if not mine.any() and not stations:
            continue
        file_name = storey_slug(index + 1, name)
        _draw_storey(plan, evaluation, states, mine & ~ceiling, mine & ceiling, stations, lo, hi,
                     folder / file_name, f"{title} - {name or 'all levels'}")
        written.append(file_name)
    return written


def storey_bands(z: np.ndarray, normal_z: np.ndarray, elevations: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """((N,) storey index, (N,) bool ceiling) of surface points at heights z (N,) with normals'
    z (N,), given the storeys' sorted elevations (M,). A level surface facing down (the planner
    turns each sample's normal towards the stations that see it, whatever the model's winding)
    more than ``CEILING_ABOVE_FLOOR_M`` over a storey's elevation is that storey's ceiling (the
    highest such storey); anything else belongs to the storey whose band, from half a metre under
    its elevation to half a metre under the next one's, holds it."""
    down = normal_z <= -0.9
    above = np.searchsorted(elevations + CEILING_ABOVE_FLOOR_M, z, side="left") - 1
    ceiling = down & (above >= 0)
    band = np.clip(np.searchsorted(elevations[1:] - 0.5, z, side="right"), 0, len(elevations) - 1)
    return np.where(ceiling, above, band), ceiling


def _draw_storey(plan: SurveyPlan, evaluation: PlanEvaluation, states: np.ndarray, below: np.ndarray,
                 above: np.ndarray, stations: list, lo: np.ndarray, hi: np.ndarray, path: Path, title: str) -> None:
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    space = plan.space
    samples = space.samples
    figure = Figure(figsize=(16, 8.2), layout="constrained")
    axes = figure.subplots(1, 2, sharex=True, sharey=True)
    colors = np.array(list(STATE_COLORS.values()))
    by_component = {e.component: e for e in evaluation.elements}
    for axis, members, heading in ((axes[0], below, "walls and floor (seen from above)"),
                                   (axes[1], above, "ceiling (seen from below)")):
        index = np.flatnonzero(members)
        if len(index) > MAX_DOTS:
            index = index[:: int(np.ceil(len(index) / MAX_DOTS))]
        # never seen at the bottom, then covered, then what falls short on top: what a plan misses shows
        index = index[np.argsort(DRAW_ORDER[states[index]], kind="stable")]
        axis.scatter(samples.xyz[index, 0], samples.xyz[index, 1], s=2.0, c=colors[states[index]], linewidths=0,
                     antialiased=False,
                     rasterized=True)
        for component in np.unique(samples.component[index]):
            element = by_component[int(component)]
            if element.status != "short":
                continue
            mine = index[samples.component[index] == component]
            x, y = samples.xyz[mine, 0].mean(), samples.xyz[mine, 1].mean()
            axis.plot(x, y, marker="x", color="#d62728", markersize=8, markeredgewidth=2)
            axis.annotate(f"{100 * element.covered_fraction:.0f}%", (x, y), xytext=(4, 4), textcoords="offset points",
                          fontsize=7, color="#d62728")
        _draw_stations(axis, plan, stations)
        frame_plan_view(axis, heading, lo, hi)
    axes[0].set_ylabel("y (m)")
    handles = [Line2D([], [], marker="o", linestyle="", color=c, label=n) for n, c in STATE_COLORS.items()]
    handles += [Line2D([], [], marker="x", linestyle="", color="#d62728", markeredgewidth=2,
                       label=f"element short of {100 * space.config.coverage[0]:g} %" if len(space.config.coverage) == 1
                       else "element short of its class's coverage"),
                Line2D([], [], marker="o", linestyle="", markerfacecolor="white", markeredgecolor="black",
                       label="station (scan order)"),
                Line2D([], [], color="#555555", linewidth=0.8, label="registers with")]
    figure.legend(handles=handles, loc="outside lower center", ncols=len(handles), frameon=False, fontsize=9)
    figure.suptitle(title, fontsize=11)
    save_png(figure, path, dpi=100)


def frame_plan_view(axis, heading: str, lo: np.ndarray, hi: np.ndarray) -> None:  # type: ignore[no-untyped-def]
    """A plan view's title, equal axes and limits (the xy box ``lo``..``hi`` and a metre around)."""
    axis.set_title(heading, fontsize=10)
    axis.set_aspect("equal")
    axis.set_xlim(lo[0] - 1, hi[0] + 1)
    axis.set_ylim(lo[1] - 1, hi[1] + 1)
    axis.set_xlabel("x (m)")


def _draw_stations(axis, plan: SurveyPlan, stations: list) -> None:
    """Registration edges (grey), the scan order (arrows) and the numbered stations."""
    space = plan.space
    ids = {s.id for s in stations}
    position = {s.id: s.position for s in plan.stations}
    for a, b, *_ in (e for e in _edges(plan) if e[0] in ids or e[1] in ids):
        axis.plot([position[a][0], position[b][0]], [position[a][1], position[b][1]], color="#555555",
                  linewidth=0.6, alpha=0.6, zorder=3)
    ordered = sorted(stations, key=lambda s: s.id)
    for first, second in zip(ordered, ordered[1:]):
        axis.annotate("", xy=second.position[:2], xytext=first.position[:2],
                      arrowprops={"arrowstyle": "->", "color": "#1f77b4", "linewidth": 1.0}, zorder=4)
    for s in ordered:
        axis.plot(s.position[0], s.position[1], marker="o", markersize=13, markerfacecolor="white",
                  markeredgecolor="black", zorder=5)
        axis.annotate(str(s.id), s.position[:2], ha="center", va="center", fontsize=7, zorder=6)
    del space


def _edges(plan: SurveyPlan) -> list[tuple[int, int]]:
    space = plan.space
    chosen = np.asarray(plan.chosen)
    return [(a, b) for a in range(len(chosen)) for b in range(a + 1, len(chosen)) if space.edges[chosen[a], chosen[b]]]

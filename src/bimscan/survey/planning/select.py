"""Choosing the stations: the fewest candidate positions whose summed density covers each class
enough, joined into one registration graph.

The problem (``CoverProblem``): samples with an area, a class and a density from every candidate;
a sample is covered when the chosen candidates' densities on it sum to the asked density; class
``k`` needs ``need_m2[k]`` of its area covered; the chosen candidates must be connected in the
registration graph (within each part of the candidates' graph: a part no candidate links to the
rest cannot be joined by any choice).

- ``greedy_cover``: the classic greedy set cover (Chvatal 1979) made connected: the first
  candidate is the one that covers most; each next one is reached through the graph from those
  chosen, the best gain per station added along the shortest path (a path of stations that only
  link counts as stations too). Gain is the area newly covered where a class still lacks some,
  plus a quarter of the progress towards the density on samples not yet covered (two stations
  that each give 600 points/m^2 cover together what neither covers alone).
- ``improve_cover`` (two stations that register to each other replaced by one) and
  ``iterated_greedy`` (Jacobs and Brusco 1995: take a few neighbouring stations out, complete the
  rest greedily, keep what is no worse) improve the greedy answer.
- ``milp_cover``: the exact problem as a mixed-integer program for scipy's HiGHS on surface groups
  (the samples the same candidates cover alone, merged): binary ``x_j`` (candidate chosen) and
  ``y_g`` (group covered), ``y_g <= sum_{j covers g alone} x_j``, ``sum_{g in k} a_g y_g >= need_k``;
  connectivity by cuts added while the solution falls apart (for a part C of the chosen set and a
  chosen station b outside it: some neighbour of C must be chosen). Asked to beat the search's
  count, within a time budget; a solution also covers with the densities summed.
- ``repair_cover`` and ``prune_cover``: a choice is completed greedily (joined in the graph
  first), then any station whose removal keeps the cover and the graph is dropped.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy import sparse

from bimscan.survey.planning.graph import graph_parts

SOFT_GAIN = 0.25  # weight of the progress towards the density on samples not yet covered
PATH_TRIALS = 8  # candidates whose path from the chosen set is evaluated exactly each greedy step


@dataclass(frozen=True)
class CoverProblem:
    """density: (S, K) sparse points/m^2 of every candidate on every sample (within the incidence
    limit); area_m2 (S,); klass (S,) int64 class index (-1: not to be covered); need_m2 (N,) area of
    each class to cover; threshold_pts_m2: the asked density; edges (K, K) bool registration graph.
    Build it with ``CoverProblem.of``: only the samples that count, in CSC order, with each
    candidate's column kept apart for fast sums."""

    density: sparse.csc_matrix
    area_m2: np.ndarray
    klass: np.ndarray
    need_m2: np.ndarray
    threshold_pts_m2: float
    edges: np.ndarray

    @staticmethod
    def of(density: sparse.spmatrix, area_m2: np.ndarray, klass: np.ndarray, need_m2: np.ndarray,
           threshold_pts_m2: float, edges: np.ndarray) -> CoverProblem:
        """The problem on the samples that count (klass >= 0): the others never change a choice."""
        rows = np.flatnonzero(klass >= 0)
        matrix = sparse.csc_matrix(density)[rows]
        matrix.sort_indices()
        return CoverProblem(density=matrix, area_m2=area_m2[rows], klass=klass[rows], need_m2=need_m2,
                            threshold_pts_m2=threshold_pts_m2, edges=edges)

    @property
    def n_candidates(self) -> int:
        return int(self.density.shape[1])

    def summed(self, chosen: np.ndarray | list[int]) -> np.ndarray:
        """(S,) float64: the chosen candidates' summed density on every sample."""
        chosen = np.asarray(chosen, dtype=np.int64)
        d = self.density
        if len(chosen) == 0:
            return np.zeros(d.shape[0])
        parts = [slice(d.indptr[j], d.indptr[j + 1]) for j in chosen]
        return np.bincount(np.concatenate([d.indices[p] for p in parts]),
                           weights=np.concatenate([d.data[p] for p in parts]), minlength=d.shape[0])

    def covered_m2(self, summed: np.ndarray) -> np.ndarray:
        """(N,) area of each class covered by a summed density (S,)."""
        # the uncovered samples weigh zero: the sums are those over the covered ones, bit for bit
        weights = np.where((summed >= self.threshold_pts_m2) & (self.klass >= 0), self.area_m2, 0.0)
        return np.bincount(self._class_index, weights=weights, minlength=len(self.need_m2))

    def deficit_m2(self, summed: np.ndarray, *, covered_m2: np.ndarray | None = None) -> np.ndarray:
        """(N,) area each class still lacks (0 where met), with a little slack for float sums;
        ``covered_m2``: ``covered_m2(summed)`` when already known."""
        lack = self.need_m2 - (self.covered_m2(summed) if covered_m2 is None else covered_m2)
        return np.where(lack > 1e-9 * np.maximum(self.need_m2, 1.0), lack, 0.0)

    def covers(self, chosen: np.ndarray | list[int]) -> bool:
        return not self.deficit_m2(self.summed(chosen)).any()

    def parts(self, chosen: np.ndarray | list[int]) -> int:
        """How many connected parts the chosen candidates form in the registration graph."""
        return int(graph_parts(self.edges, np.asarray(chosen, dtype=np.int64)).max() + 1) if len(chosen) else 0

    @cached_property
    def _class_index(self) -> np.ndarray:
        """(S,) int64: each sample's class, 0 for those not to cover (they weigh nothing)."""
        return np.maximum(self.klass, 0)

    @cached_property
    def _entry_column(self) -> np.ndarray:
        """(nnz,) int64: the candidate of each stored density (the matrix's CSC order)."""
        return np.repeat(np.arange(self.n_candidates), np.diff(self.density.indptr))

    @cached_property
    def column_totals(self) -> np.ndarray:
        """(K,) float64: each candidate's density summed over every sample."""
        return np.asarray(self.density.sum(axis=0)).ravel()

    def _open_entries(self, summed: np.ndarray, wanting: np.ndarray) -> np.ndarray:
        """Indices of the stored densities that can still change a gain: on samples under the
        density, of a class that lacks area (the others add exactly zero), in CSC order."""
        open_sample = (summed < self.threshold_pts_m2) & (self.klass >= 0) & wanting[np.maximum(self.klass, 0)]
        return np.flatnonzero(open_sample[self.density.indices])

    def gains(self, summed: np.ndarray, *, deficit_m2: np.ndarray | None = None) -> np.ndarray:
        """(K,) the greedy gain of adding each candidate to a choice with this summed density
        (``deficit_m2``: ``deficit_m2(summed)`` when already known)."""
        deficit = self.deficit_m2(summed) if deficit_m2 is None else deficit_m2
        wanting = deficit > 0
        entries = self._open_entries(summed, wanting)
        rows = self.density.indices[entries]
        klass = self.klass[rows]
        before = summed[rows]
        after = before + self.density.data[entries]
        threshold = self.threshold_pts_m2
        area = self.area_m2[rows]
        newly = area * ((before < threshold) & (after >= threshold))
        progress = area * (np.minimum(after, threshold) - np.minimum(before, threshold)) / threshold
        index = self._entry_column[entries] * len(self.need_m2) + klass
        shape = (self.n_candidates, len(self.need_m2))
        hard = np.bincount(index, weights=newly, minlength=shape[0] * shape[1]).reshape(shape)
        soft = np.bincount(index, weights=progress, minlength=shape[0] * shape[1]).reshape(shape)
        return (np.minimum(hard, deficit[None, :]) + SOFT_GAIN * soft * wanting[None, :]).sum(axis=1)


def _neighbours(edges: np.ndarray) -> list[list[int]]:
    """Each candidate's neighbours in the graph ``edges`` (K, K) bool, in index order."""
    return [np.flatnonzero(row).tolist() for row in edges]


def _paths_from(neighbours: list[list[int]], chosen: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """Breadth-first search from the chosen set over a graph's ``_neighbours``: (K,) hops (-1
    unreachable, 0 chosen), (K,) parent."""
    hops = [-1] * len(neighbours)
    parent = [-1] * len(neighbours)
    queue = deque(int(c) for c in chosen)
    for c in queue:
        hops[c] = 0
    while queue:
        node = queue.popleft()
        for other in neighbours[node]:
            if hops[other] < 0:
                hops[other] = hops[node] + 1
                parent[other] = node
                queue.append(other)
    return np.array(hops, dtype=np.int64), np.array(parent, dtype=np.int64)


def _path(parent: np.ndarray, hops: np.ndarray, end: int) -> list[int]:
    """The candidates from the chosen set's neighbour to ``end``, in order (the chosen end excluded)."""
    path = [end]
    while hops[path[-1]] > 1:
        path.append(int(parent[path[-1]]))
    return path[::-1]


def greedy_cover(problem: CoverProblem, *, start: list[int] | None = None,
                 allowed: np.ndarray | None = None) -> list[int]:
    """The connected greedy cover (see the module docs), continuing from ``start`` (a partial
    choice) when given; only ``allowed`` (K,) bool candidates are added. Returns the choice in the
    order added; it covers the need when any choice of the allowed candidates can."""
    chosen = list(start or [])
    allowed = np.ones(problem.n_candidates, dtype=bool) if allowed is None else allowed
    summed = problem.summed(chosen)
    linked = _neighbours(problem.edges & allowed[None, :] & allowed[:, None])
    while True:
        covered = problem.covered_m2(summed)
        deficit = problem.deficit_m2(summed, covered_m2=covered)
        if not deficit.any():
            break
        gains = problem.gains(summed, deficit_m2=deficit)
        gains[chosen] = 0.0
        gains[~allowed] = 0.0
        hops, parent = _paths_from(linked, chosen)
        reachable = np.flatnonzero(hops > 0)
        add, best_value = [], 0.0
        if len(reachable):
            # a path's gain is at most the sum of its stations' own gains: try the best few exactly
            estimate = np.array([sum(gains[p] for p in _path(parent, hops, int(j))) / hops[j] for j in reachable])
            for j in reachable[np.argsort(-estimate, kind="stable")[:PATH_TRIALS]]:
                path = _path(parent, hops, int(j))
                trial = summed + problem.summed(path)
                value = _progress(problem, summed, trial, deficit_m2=deficit, covered_m2=covered) / len(path)
                if value > best_value + 1e-12:
                    best_value, add = value, path
        # a part of the candidates' graph the chosen cannot reach: it needs its own stations anyway
        unreachable = np.flatnonzero((hops < 0) & (gains > 0))
        if len(unreachable) and gains[unreachable].max() > best_value + 1e-12:
            add = [int(unreachable[np.argmax(gains[unreachable])])]
        if not add:
            break
        chosen.extend(add)
        summed = summed + problem.summed(add)
    return chosen


def _progress(problem: CoverProblem, before: np.ndarray, after: np.ndarray, *, deficit_m2: np.ndarray,
              covered_m2: np.ndarray) -> float:
    """The greedy gain of going from one summed density to another (as ``CoverProblem.gains``);
    ``deficit_m2`` and ``covered_m2``: the problem's figures of ``before``."""
    deficit = deficit_m2
    hard = np.minimum(problem.covered_m2(after) - covered_m2, deficit).sum()
    counted = problem.klass >= 0
    wanting = deficit[np.maximum(problem.klass, 0)] > 0
    t = problem.threshold_pts_m2
    soft = (problem.area_m2 * (np.minimum(after, t) - np.minimum(before, t)) / t)[counted & wanting].sum()
    return float(hard + SOFT_GAIN * soft)


def prune_cover(problem: CoverProblem, chosen: list[int]) -> list[int]:
    """Drop stations, the least useful first, while the rest still covers the need and forms no
    more graph parts than before."""
    chosen = list(chosen)
    parts = problem.parts(chosen)
    changed = True
    while changed and len(chosen) > 1:
        changed = False
        summed = problem.summed(chosen)
        alone = problem.column_totals[chosen]  # least total density first
        for j in [chosen[i] for i in np.argsort(alone, kind="stable")]:
            rest = [c for c in chosen if c != j]
            without = summed - problem.summed([j])
            if not problem.deficit_m2(without).any() and problem.parts(rest) <= parts:
                chosen = rest
                changed = True
                break
    return chosen


def repair_cover(problem: CoverProblem, chosen: list[int], *, allowed: np.ndarray | None = None) -> list[int]:
    """Complete a choice that falls short on the whole surface (or falls apart in the graph):
    greedily connected, then pruned."""
    chosen = list(chosen)
    if len(chosen) > 1 and problem.parts(chosen) > 1:
        chosen = join_parts(problem, chosen)
    return prune_cover(problem, greedy_cover(problem, start=chosen, allowed=allowed))


def join_parts(problem: CoverProblem, chosen: list[int]) -> list[int]:
    """The choice with candidates added along shortest graph paths until its parts are joined,
    wherever the graph joins them (a part at a time, to its nearest other part)."""
    chosen = list(chosen)
    neighbours = _neighbours(problem.edges)
    while True:
        parts = graph_parts(problem.edges, np.array(chosen))
        joined = False
        for part in range(int(parts.max()) + 1):
            members = [c for c, p in zip(chosen, parts) if p == part]
            hops, parent = _paths_from(neighbours, members)
            others = [c for c, p in zip(chosen, parts) if p != part and hops[c] > 0]
            if others:
                target = min(others, key=lambda c: hops[c])
                chosen.extend(p for p in _path(parent, hops, target)[:-1] if p not in chosen)
                joined = True
                break
        if not joined:
            return chosen


def improve_cover(problem: CoverProblem, chosen: list[int], *, allowed: np.ndarray | None = None,
                  max_rounds: int = 50) -> list[int]:
    """Local search on a cover: replace two stations that register to each other by one candidate
    that keeps the cover and the graph whole, while such a pair exists (then prune)."""
    chosen = prune_cover(problem, list(chosen))
    allowed = np.ones(problem.n_candidates, dtype=bool) if allowed is None else allowed
    parts = problem.parts(chosen)
    for _ in range(max_rounds):
        replaced = False
        summed = problem.summed(chosen)
        pairs = [(a, b) for i, a in enumerate(chosen) for b in chosen[i + 1:] if problem.edges[a, b]]
        for a, b in pairs:
            rest = [c for c in chosen if c not in (a, b)]
            without = summed - problem.summed([a, b])
            deficit = problem.deficit_m2(without)
            newly = _newly_covered(problem, without)
            enough = np.all(newly >= deficit[None, :] - 1e-9, axis=1) & allowed
            enough[rest] = False
            for c in np.flatnonzero(enough)[np.argsort(-newly[enough].sum(axis=1), kind="stable")]:
                trial = rest + [int(c)]
                if problem.covers(trial) and problem.parts(trial) <= parts:
                    chosen, replaced = prune_cover(problem, trial), True
                    break
            if replaced:
                break
        if not replaced:
            break
    return chosen


def iterated_greedy(problem: CoverProblem, chosen: list[int], *, allowed: np.ndarray | None = None,
                    rounds: int = 200, seed: int = 0) -> list[int]:
    """Iterated greedy search (Jacobs and Brusco 1995, for set covering): take out a station and
    up to two of the chosen stations it registers to, complete the rest again greedily (joined in
    the graph first), prune and improve; keep the result when it has no more stations and graph
    parts than the current one (equal moves let the search drift). ``rounds`` and ``seed`` fix the
    search: the same problem gives the same answer. It stops early once ``max(20, 10 x stations)``
    rounds in a row gave back the choice they started from."""
    allowed = np.ones(problem.n_candidates, dtype=bool) if allowed is None else allowed
    rng = np.random.default_rng(seed)
    current = list(chosen)
    best = list(chosen)
    parts = problem.parts(current)
    unchanged = 0
    for round_ in range(rounds):
        # a plan of a few stations has few neighbours to try: stop once they all came back unchanged
        if len(current) <= 1 or unchanged >= max(20, 10 * len(current)):
            break
        unchanged += 1
        first = current[int(rng.integers(len(current)))]
        linked = [c for c in current if c != first and problem.edges[first, c]]
        out = {first, *(linked[i] for i in rng.permutation(len(linked))[:round_ % 3])}
        rest = [c for c in current if c not in out]
        if len(rest) > 1 and problem.parts(rest) > parts:
            rest = join_parts(problem, rest)
        trial = greedy_cover(problem, start=rest, allowed=allowed)
        if not problem.covers(trial):
            continue
        trial = prune_cover(problem, trial)
        if problem.parts(trial) > parts or len(trial) > len(current):
            continue
        if sorted(trial) != sorted(current):
            unchanged = 0
        current = trial
        if len(current) < len(best):
            best = improve_cover(problem, current, allowed=allowed)
            current = list(best)
    return best


def _newly_covered(problem: CoverProblem, summed: np.ndarray) -> np.ndarray:
    """(K, N): the area of each class that adding each candidate would newly cover."""
    entries = problem._open_entries(summed, np.ones(len(problem.need_m2), dtype=bool))
    rows = problem.density.indices[entries]
    before = summed[rows]
    threshold = problem.threshold_pts_m2
    newly = problem.area_m2[rows] * ((before < threshold) & (before + problem.density.data[entries] >= threshold))
    shape = (problem.n_candidates, len(problem.need_m2))
    index = problem._entry_column[entries] * shape[1] + problem.klass[rows]
    return np.bincount(index, weights=newly, minlength=shape[0] * shape[1]).reshape(shape)


@dataclass(frozen=True)
class MilpResult:
    """What the MILP found: chosen (candidate indices) or None, its status in words ("optimal",
    "time limit", "infeasible", "too large"), the lower bound it proved (None when none), the
    size of the model (surface groups), cut rounds and seconds."""

    chosen: list[int] | None
    status: str
    bound: float | None
    groups: int
    rounds: int
    seconds: float


def surface_groups(problem: CoverProblem) -> tuple[np.ndarray, sparse.csr_matrix, np.ndarray, np.ndarray]:
    """The samples that count, merged where the same candidates cover them alone (at the asked
    density from that candidate by itself) in the same class: (G,) class, (G, K) 0/1 which
    candidates cover each group, (G,) area, (S,) each sample's group (-1: none)."""
    alone = (problem.density >= problem.threshold_pts_m2).tocsr()
    alone.sort_indices()
    counted = (problem.klass >= 0) & (np.diff(alone.indptr) > 0)
    index = np.flatnonzero(counted)
    keys: dict[tuple[int, bytes], int] = {}
    group = np.full(len(problem.klass), -1, dtype=np.int64)
    for i in index:
        key = (int(problem.klass[i]), alone.indices[alone.indptr[i]:alone.indptr[i + 1]].tobytes())
        group[i] = keys.setdefault(key, len(keys))
    first = np.full(len(keys), -1, dtype=np.int64)
    first[group[index][::-1]] = index[::-1]
    klass = problem.klass[first]
    cover = alone[first].astype(np.float64)
    area = np.bincount(group[index], weights=problem.area_m2[index], minlength=len(keys))
    return klass, cover.tocsr(), area, group


def milp_cover(problem: CoverProblem, *, at_most: int, max_groups: int, time_limit_s: float) -> MilpResult:
    """The fewest stations covering every class's need (at most ``at_most``), connected, as a
    mixed-integer program for scipy's HiGHS (see the module docs), on the surface groups of
    ``surface_groups`` (a sample is counted covered only by a station that covers it alone, so a
    solution also covers with the densities summed). Not run ("too large") beyond ``max_groups``."""
    from scipy.optimize import Bounds, LinearConstraint, milp

    start = time.perf_counter()
    klass, cover, area, _ = surface_groups(problem)
    g, k = cover.shape
    if g > max_groups:
        return MilpResult(chosen=None, status="too large", bound=None, groups=g, rounds=0, seconds=0.0)
    n_classes = len(problem.need_m2)
    wanting = np.flatnonzero(problem.need_m2 > 0)
    rows = [LinearConstraint(sparse.hstack([-cover, sparse.identity(g, format="csr")], format="csr"), -np.inf, 0.0),
            LinearConstraint(sparse.csr_matrix((area, (klass, k + np.arange(g))), shape=(n_classes, k + g))[wanting],
                             problem.need_m2[wanting], np.inf),
            LinearConstraint(sparse.csr_matrix(np.r_[np.ones(k), np.zeros(g)][None, :]), 0, at_most)]
    cost = np.r_[np.ones(k), np.zeros(g)]
    cuts: list[np.ndarray] = []
    candidate_parts = graph_parts(problem.edges)
    rounds, bound, status, chosen = 0, None, "time limit", None
    while True:
        left = time_limit_s - (time.perf_counter() - start)
        if left <= 0.5:
            break
        constraints = list(rows)
        if cuts:
            constraints.append(LinearConstraint(sparse.csr_matrix(np.array(cuts)), -1.0, np.inf))
        result = milp(cost, integrality=np.ones(k + g), bounds=Bounds(0, 1), constraints=constraints,
                      options={"time_limit": left, "disp": False})
        rounds += 1
        dual = getattr(result, "mip_dual_bound", None)
        bound = float(dual) if dual is not None and np.isfinite(dual) else bound
        if result.x is None:
            status = "infeasible" if result.status == 2 else "time limit"
            break
        picked = [int(j) for j in np.flatnonzero(result.x[:k] > 0.5)]
        new_cuts = _connectivity_cuts(problem.edges, candidate_parts, picked, k + g)
        chosen = picked
        if not new_cuts:
            status = "optimal" if result.status == 0 else "time limit"
            break
        cuts.extend(new_cuts)  # disconnected: cut it off and solve again (kept as a start for repair)
    return MilpResult(chosen=chosen, status=status, bound=bound, groups=g, rounds=rounds,
                      seconds=time.perf_counter() - start)


def _connectivity_cuts(edges: np.ndarray, candidate_parts: np.ndarray, picked: list[int],
                       n_variables: int) -> list[np.ndarray]:
    """Cuts that a connected choice satisfies and ``picked`` breaks: for each part C of the picked
    set and a picked b outside C in the same part of the candidates' graph,
    sum_{j in N(C)} x_j - x_a - x_b >= -1 (a in C)."""
    if len(picked) < 2:
        return []
    picked_array = np.array(picked)
    parts = graph_parts(edges, picked_array)
    cuts = []
    for p in range(int(parts.max()) + 1):
        inside = picked_array[parts == p]
        outside = picked_array[(parts != p) & (candidate_parts[picked_array] == candidate_parts[inside[0]])]
        if len(outside) == 0:
            continue
        boundary = np.flatnonzero(edges[inside].any(axis=0))
        boundary = boundary[~np.isin(boundary, inside)]
        row = np.zeros(n_variables)
        row[boundary] = 1.0
        row[inside[0]] -= 1.0
        row[outside[0]] -= 1.0
        cuts.append(row)
    return cuts

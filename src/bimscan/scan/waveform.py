"""The scan path with sensor effects: footprint sub-rays, transparent surfaces, waveform returns.

One chunk of mirror lines goes through these steps (``scan_chunk``), all rays through the
engine's ``cast``, all per-ray work in fused Numba kernels over fixed blocks:

1. The centre ray of every pulse is cast (with one extra line on each side of the chunk when the
   footprint is adaptive, so a pulse's neighbours are known whatever the chunking).
2. Rays that hit a transparent surface are cast again from just beyond it, up to
   ``max_glass_layers`` times (``cast_layers``).
3. ``flag_edges`` marks the pulses whose footprint may straddle an edge: a neighbour in the scan
   grid (the pulses before and after it on its line, the nearest pulses of the lines before and
   after) hits another component or nothing, or its range departs by more than ``edge_depth_m``
   from the straight line through its neighbours' ranges. Only those pulses get the sub-rays of
   HELIOS++'s pattern (``subray_pattern``), so the footprint costs rays only near edges.
4. ``gather_returns`` turns each pulse's hits into echoes (energy = sub-ray weight x transmission
   x reflectance x |cos(incidence)|), merges echoes closer than the range resolution (c * pulse
   length / 2) into returns at their energy-weighted range (mixed pixels), labels each return by
   the component with the largest energy share, draws its detection from the range equation with
   speckle, and keeps the returns the ``returns`` mode asks for.
5. ``finish_returns`` makes points: range noise (growing with range and 1 / cos(incidence) when
   geometric noise is on), angle noise, surface waviness, intensity, colour, time, return numbers.

Every random draw is keyed by (station key, pulse number, purpose): outputs do not depend on the
chunk size or the thread count.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np
from scipy.special import gammainccinv

from bimscan.scan.kernels import (
    _BLOCK, _FAST, beam_basis, draw_normal, draw_uniform, pulse_normals, recorded_direction,
)

MODE_CODES = {"first": 0, "last": 1, "strongest": 2, "all": 3}
GLASS_STEP_M = 1e-4  # a ray cast on beyond a transparent hit starts this far past it
# Purposes of the random draws (see kernels.draw_bits): disjoint ranges.
_P_GLASS = 1 << 12  # + sub-ray * 64 + layer
_P_DETECT = 1 << 20  # + echo cluster index
_P_RANGE = 1 << 21  # + return index
_P_COLOR = 1 << 22  # + return index


def subray_pattern(quality: int, divergence_rad: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """HELIOS++'s sub-ray pattern: a centre ray and rings j = 1..Q-1 of 6j sub-rays.

    Ring j lies at j / (Q - 1) of the beam's half divergence (the outer ring on the footprint's
    1/e^2 edge; HELIOS++ steps rings by divergence / Q), its sub-rays at azimuths 2 pi k / (6j).
    Each sub-ray stands for an equal area of the footprint (a quarter less for the centre) and
    carries the Gaussian irradiance exp(-2 (r / w)^2) there; weights sum to 1.
    Returns (off-axis angle (S,) rad, azimuth about the axis (S,) rad, weight (S,)); index 0 is
    the centre ray.
    """
    angles, azimuths, weights = [0.0], [0.0], [0.75]
    for ring in range(1, quality):
        fraction = ring / (quality - 1)
        for k in range(6 * ring):
            angles.append(fraction * divergence_rad / 2.0)
            azimuths.append(2.0 * math.pi * k / (6 * ring))
            weights.append(math.exp(-2.0 * fraction * fraction))
    w = np.array(weights)
    return np.array(angles), np.array(azimuths), w / w.sum()


def detection_constant(speckle_cells: int) -> float:
    """a with Q(M, a) = 1/2 (the median of a Gamma(M, 1) variable).

    The received power of a return is Gamma distributed with shape M (speckle averaged over M
    cells; Goodman, Speckle Phenomena in Optics, 2007) and mean s times the mean at the
    datasheet's reach, where half the pulses are detected; so the threshold is crossed with
    probability Q(M, a / s) (regularised upper incomplete gamma). M = 1: exp(-ln 2 / s).
    """
    return float(gammainccinv(speckle_cells, 0.5))


@nb.njit(cache=True, inline="always")
def detection_probability(s: float, a: float, cells: int) -> float:
    """Q(M, a / s) for integer M: exp(-x) * sum_{k < M} x^k / k!, x = a / s."""
    if s <= 0.0:
        return 0.0
    x = a / s
    term = 1.0
    total = 1.0
    for k in range(1, cells):
        term *= x / k
        total += term
    return math.exp(-x) * total


@nb.njit(cache=True, inline="always")
def _surface(t: float, tri: np.uint32, face_component: np.ndarray, min_range: float, max_range: float) -> int:
    """The component a hit belongs to, or -1 for a miss or a hit outside the range limits."""
    if tri < len(face_component) and t >= min_range and t <= max_range:
        return face_component[tri]
    return -1


# Which neighbours of a pulse disagree with it (flag_edges' bits), and the direction of each, as an
# azimuth about the beam in footprint_rays' basis (u towards increasing azimuth, v up).
TOWARDS = {1: 1.5 * math.pi, 2: 0.5 * math.pi, 4: math.pi, 8: 0.0}  # previous / next pulse, previous / next line


@nb.njit(cache=True, parallel=True)
def flag_edges(t: np.ndarray, tri: np.ndarray, face_component: np.ndarray, min_range: float, max_range: float,
               offsets: np.ndarray, counts: np.ndarray, shift_next: np.ndarray, first: int, stop: int,
               edge_depth_m: float, flag: np.ndarray) -> None:
    """flag (n,) uint8: for pulses of lines first..stop-1, which grid neighbours disagree with it.

    Bits: 1 the previous pulse of its line (lower), 2 the next (higher), 4 the nearest pulse of the
    line before (smaller azimuth), 8 of the line after. A neighbour disagrees when it hits another
    component or nothing, or when the pulse's range departs from the straight line through the
    two neighbours on that axis by more than ``edge_depth_m`` (both then count). offsets/counts:
    where each line's rays begin and how many; shift_next[j]: index shift from a pulse of line j to
    the pulse of line j + 1 nearest in elevation. Lines first - 1 and stop (when present) are read
    as neighbours only.
    """
    n_lines = len(counts)
    for j in nb.prange(first, stop):
        base = offsets[j]
        n = counts[j]
        for m in range(n):
            i = base + m
            c = _surface(t[i], tri[i], face_component, min_range, max_range)
            bits = 0
            lower = i - 1 if m > 0 else -1
            upper = i + 1 if m + 1 < n else -1
            below = -1
            above = -1
            if j > 0:
                mm = m - shift_next[j - 1]
                if mm >= 0 and mm < counts[j - 1]:
                    below = offsets[j - 1] + mm
            if j + 1 < n_lines:
                mm = m + shift_next[j]
                if mm >= 0 and mm < counts[j + 1]:
                    above = offsets[j + 1] + mm
            if lower >= 0 and _surface(t[lower], tri[lower], face_component, min_range, max_range) != c:
                bits |= 1
            if upper >= 0 and _surface(t[upper], tri[upper], face_component, min_range, max_range) != c:
                bits |= 2
            if below >= 0 and _surface(t[below], tri[below], face_component, min_range, max_range) != c:
                bits |= 4
            if above >= 0 and _surface(t[above], tri[above], face_component, min_range, max_range) != c:
                bits |= 8
            if c >= 0 and lower >= 0 and upper >= 0 and (bits & 3) == 0:
                if abs(float(t[lower]) - 2.0 * float(t[i]) + float(t[upper])) > edge_depth_m:
                    bits |= 3
            if c >= 0 and below >= 0 and above >= 0 and (bits & 12) == 0:
                if abs(float(t[below]) - 2.0 * float(t[i]) + float(t[above])) > edge_depth_m:
                    bits |= 12
            flag[i] = bits


@nb.njit(cache=True, parallel=True)
def probe_rays(rays: np.ndarray, pulses: np.ndarray, bits: np.ndarray, offsets: np.ndarray, half_divergence: float,
               out: np.ndarray) -> None:
    """out (K, 6) float32: for each pulse of ``pulses`` one ray at the footprint's edge towards each
    disagreeing neighbour (``bits``, see flag_edges); ``offsets`` (len(pulses) + 1): where each
    pulse's probes begin."""
    c_off, s_off = math.cos(half_divergence), math.sin(half_divergence)
    for q in nb.prange(len(pulses)):
        i = pulses[q]
        dx, dy, dz = float(rays[i, 3]), float(rays[i, 4]), float(rays[i, 5])
        ux, uy, uz, vx, vy, vz = beam_basis(dx, dy, dz)
        k = offsets[q]
        for bit in range(4):
            if bits[q] & (1 << bit):
                # 1: -v (lower), 2: +v (higher), 4: -u (previous line), 8: +u (next line)
                su = -1.0 if bit == 2 else (1.0 if bit == 3 else 0.0)
                sv = -1.0 if bit == 0 else (1.0 if bit == 1 else 0.0)
                out[k, 0] = rays[i, 0]
                out[k, 1] = rays[i, 1]
                out[k, 2] = rays[i, 2]
                out[k, 3] = c_off * dx + s_off * (su * ux + sv * vx)
                out[k, 4] = c_off * dy + s_off * (su * uy + sv * vy)
                out[k, 5] = c_off * dz + s_off * (su * uz + sv * vz)
                k += 1


@nb.njit(cache=True, parallel=True)
def straddling(pulses: np.ndarray, offsets: np.ndarray, t0: np.ndarray, tri0: np.ndarray, t_probe: np.ndarray,
               tri_probe: np.ndarray, face_component: np.ndarray, min_range: float, max_range: float,
               edge_depth_m: float) -> np.ndarray:
    """(len(pulses),) bool: whether any probe of a pulse meets another surface than its centre ray
    (another component, nothing, or a range more than ``edge_depth_m`` away)."""
    out = np.zeros(len(pulses), dtype=np.bool_)
    for q in nb.prange(len(pulses)):
        i = pulses[q]
        c = _surface(t0[i], tri0[i], face_component, min_range, max_range)
        for k in range(offsets[q], offsets[q + 1]):
            cp = _surface(t_probe[k], tri_probe[k], face_component, min_range, max_range)
            if cp != c or (c >= 0 and abs(float(t_probe[k]) - float(t0[i])) > edge_depth_m):
                out[q] = True
    return out


@nb.njit(cache=True, parallel=True)
def footprint_rays(rays: np.ndarray, flagged: np.ndarray, cos_off: np.ndarray, sin_off: np.ndarray,
                   cos_az: np.ndarray, sin_az: np.ndarray, out: np.ndarray) -> None:
    """out (K * S', 6) float32: the sub-rays (pattern entries 1..S) of the pulses ``flagged`` (K,).

    Sub-ray s of a beam d leaves the same origin in direction cos(a) d + sin(a) (cos(phi) u +
    sin(phi) v), u horizontal and v = d x u pointing up (u = x for a vertical beam).
    """
    s_count = len(cos_off)
    for q in nb.prange(len(flagged)):
        i = flagged[q]
        dx, dy, dz = float(rays[i, 3]), float(rays[i, 4]), float(rays[i, 5])
        ux, uy, uz, vx, vy, vz = beam_basis(dx, dy, dz)
        for s in range(s_count):
            k = q * s_count + s
            cu = sin_off[s] * cos_az[s]
            cv = sin_off[s] * sin_az[s]
            out[k, 0] = rays[i, 0]
            out[k, 1] = rays[i, 1]
            out[k, 2] = rays[i, 2]
            out[k, 3] = cos_off[s] * dx + cu * ux + cv * vx
            out[k, 4] = cos_off[s] * dy + cu * uy + cv * vy
            out[k, 5] = cos_off[s] * dz + cu * uz + cv * vz


@nb.njit(cache=True)
def _passes_through(t: np.ndarray, tri: np.ndarray, transparent_face: np.ndarray) -> np.ndarray:
    out = np.zeros(len(t), dtype=np.bool_)
    for i in range(len(t)):
        out[i] = tri[i] < len(transparent_face) and math.isfinite(t[i]) and transparent_face[tri[i]]
    return out


def cast_layers(engine, rays: np.ndarray, t: np.ndarray, tri: np.ndarray, transparent_face: np.ndarray,
                max_layers: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Hits behind transparent surfaces: rays whose hit is transparent are cast on from just past it.

    Returns (ray index (K,) int64, layer (K,) int64 >= 1, range from the ray's origin (K,) float64,
    triangle (K,) uint32), ordered by layer then ray.
    """
    index = np.flatnonzero(_passes_through(t, tri, transparent_face))
    travelled = t[index].astype(np.float64)
    parts: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
    for layer in range(1, max_layers + 1):
        if len(index) == 0:
            break
        step = travelled + GLASS_STEP_M
        onward = np.empty((len(index), 6), dtype=np.float32)
        onward[:, :3] = rays[index, :3] + rays[index, 3:] * step[:, None]
        onward[:, 3:] = rays[index, 3:]
        t_next, tri_next = engine.cast(onward)
        total = step + t_next
        hit = np.isfinite(t_next)
        parts.append((index[hit], np.full(int(hit.sum()), layer, dtype=np.int64), total[hit], tri_next[hit]))
        keep = _passes_through(t_next, tri_next, transparent_face)
        index, travelled = index[keep], total[keep]
    if not parts:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros(0, np.uint32)
    return tuple(np.concatenate(column) for column in zip(*parts))  # type: ignore[return-value]


@nb.njit(cache=True, parallel=True, fastmath=_FAST)
def gather_returns(first: int, n: int, t0: np.ndarray, tri0: np.ndarray, flagged: np.ndarray, rays: np.ndarray,
                   pulse: np.ndarray, extra_offsets: np.ndarray, e_sub: np.ndarray, e_layer: np.ndarray,
                   e_t: np.ndarray, e_tri: np.ndarray, sub_weight: np.ndarray, max_echoes: int,
                   face_component: np.ndarray, face_normal: np.ndarray, reflectance: np.ndarray,
                   face_transparency: np.ndarray, glass: bool, glass_probability: float, min_range: float,
                   max_range: float, resolution_m: float, key: np.uint64, detect: bool, reach_scale: float,
                   detect_a: float, speckle_cells: int, mode: int, slots: int,
                   out_t: np.ndarray, out_comp: np.ndarray, out_tri: np.ndarray, out_energy: np.ndarray,
                   out_cos: np.ndarray, out_number: np.ndarray, out_count_of: np.ndarray, count: np.ndarray) -> None:
    """Returns of pulses first..first+n-1 (indices into the chunk's rays) into ``slots`` slots each.

    A pulse's echoes: its centre ray's hit (weight 1, or the centre's pattern weight when the pulse
    was flagged for sub-rays) and its sub-rays' hits (their pattern weights), each followed through
    transparent surfaces (weight x transparency per crossing; a crossing echoes with probability
    ``glass_probability``). Echo energy = weight x reflectance x |cos(incidence)|. Echoes sorted by
    range merge while the gap to the next is at most ``resolution_m``; a return's range is the
    energy-weighted mean, its component the one with the largest energy, its detection
    probability Q(M, a / s) with s = energy / (reach_scale * range^2). out_number / out_count_of:
    the return's number among the pulse's detected returns and their count; count (n,) how many
    slots were filled.
    """
    n_blocks = (n + _BLOCK - 1) // _BLOCK
    for b in nb.prange(n_blocks):
        et = np.empty(max_echoes)
        ee = np.empty(max_echoes)
        ec = np.empty(max_echoes, dtype=np.int32)
        etri = np.empty(max_echoes, dtype=np.uint32)
        ecos = np.empty(max_echoes)
        ct = np.empty(max_echoes)
        ce = np.empty(max_echoes)
        cc = np.empty(max_echoes, dtype=np.int32)
        ctri = np.empty(max_echoes, dtype=np.uint32)
        ccos = np.empty(max_echoes)
        for local in range(b * _BLOCK, min(n, (b + 1) * _BLOCK)):
            r = first + local
            p = pulse[r]
            dx, dy, dz = float(rays[r, 3]), float(rays[r, 4]), float(rays[r, 5])
            base = local * slots
            if not flagged[r] and extra_offsets[r] == extra_offsets[r + 1] and not (
                    glass and tri0[r] < len(face_component) and face_transparency[tri0[r]] > 0.0):
                # the common case: one opaque hit of the whole footprint, one echo, one return
                count[local] = 0
                c = _surface(float(t0[r]), tri0[r], face_component, min_range, max_range)
                if c < 0:
                    continue
                t_hit = float(t0[r])
                cosi = abs(dx * face_normal[tri0[r], 0] + dy * face_normal[tri0[r], 1] + dz * face_normal[tri0[r], 2])
                energy = reflectance[c] * cosi
                if detect and not draw_uniform(key, p, _P_DETECT) < detection_probability(
                        energy / (reach_scale * t_hit * t_hit), detect_a, speckle_cells):
                    continue
                out_t[base] = t_hit
                out_comp[base] = c
                out_tri[base] = tri0[r]
                out_energy[base] = energy
                out_cos[base] = cosi
                out_number[base] = 1
                out_count_of[base] = 1
                count[local] = 1
                continue
            ne = 0
            sub = 0
            weight = sub_weight[0] if flagged[r] else 1.0
            alive = True
            e = extra_offsets[r]
            end = extra_offsets[r + 1]
            # the centre's first hit, then the extra hits sorted by (sub-ray, layer)
            t_hit = float(t0[r])
            tri_hit = tri0[r]
            layer = 0
            while True:
                if alive and ne < max_echoes:
                    c = _surface(t_hit, tri_hit, face_component, min_range, max_range)
                    if c < 0:
                        alive = False
                    else:
                        cosi = abs(dx * face_normal[tri_hit, 0] + dy * face_normal[tri_hit, 1]
                                   + dz * face_normal[tri_hit, 2])
                        if glass and face_transparency[tri_hit] > 0.0:
                            if draw_uniform(key, p, _P_GLASS + sub * 64 + layer) < glass_probability:
                                et[ne] = t_hit
                                ee[ne] = weight * reflectance[c] * cosi
                                ec[ne] = c
                                etri[ne] = tri_hit
                                ecos[ne] = cosi
                                ne += 1
                            weight *= face_transparency[tri_hit]
                        else:
                            et[ne] = t_hit
                            ee[ne] = weight * reflectance[c] * cosi
                            ec[ne] = c
                            etri[ne] = tri_hit
                            ecos[ne] = cosi
                            ne += 1
                            alive = False
                if e >= end:
                    break
                if e_sub[e] != sub:  # the next sub-ray starts with its full pattern weight
                    sub = e_sub[e]
                    weight = sub_weight[sub]
                    alive = True
                t_hit = e_t[e]
                tri_hit = e_tri[e]
                layer = e_layer[e]
                e += 1
            # sort echoes by range (few: insertion sort)
            for i in range(1, ne):
                j = i
                while j > 0 and et[j - 1] > et[j]:
                    et[j - 1], et[j] = et[j], et[j - 1]
                    ee[j - 1], ee[j] = ee[j], ee[j - 1]
                    ec[j - 1], ec[j] = ec[j], ec[j - 1]
                    etri[j - 1], etri[j] = etri[j], etri[j - 1]
                    ecos[j - 1], ecos[j] = ecos[j], ecos[j - 1]
                    j -= 1
            # merge echoes closer than the range resolution; detect each merged return
            nc = 0
            start = 0
            cluster = 0
            while start < ne:
                stop = start + 1
                while stop < ne and et[stop] - et[stop - 1] <= resolution_m:
                    stop += 1
                energy = 0.0
                weighted = 0.0
                for k in range(start, stop):
                    energy += ee[k]
                    weighted += ee[k] * et[k]
                if energy > 0.0:
                    # the component with the largest share of the energy, and its strongest echo
                    best_c = ec[start]
                    best_share = -1.0
                    for k in range(start, stop):
                        share = 0.0
                        for q in range(start, stop):
                            if ec[q] == ec[k]:
                                share += ee[q]
                        if share > best_share:
                            best_share = share
                            best_c = ec[k]
                    strongest = start
                    for k in range(start, stop):
                        if ec[k] == best_c and (ec[strongest] != best_c or ee[k] > ee[strongest]):
                            strongest = k
                    range_m = weighted / energy
                    kept = True
                    if detect:
                        s = energy / (reach_scale * range_m * range_m)
                        kept = draw_uniform(key, p, _P_DETECT + cluster) < detection_probability(s, detect_a,
                                                                                                 speckle_cells)
                    if kept:
                        ct[nc] = range_m
                        ce[nc] = energy
                        cc[nc] = best_c
                        ctri[nc] = etri[strongest]
                        ccos[nc] = ecos[strongest]
                        nc += 1
                cluster += 1
                start = stop
            # which returns become points
            filled = 0
            if nc > 0:
                if mode == 3:
                    lo, hi = 0, min(nc, slots)
                elif mode == 0:
                    lo, hi = 0, 1
                elif mode == 1:
                    lo, hi = nc - 1, nc
                else:
                    lo = 0
                    for k in range(1, nc):
                        if ce[k] > ce[lo]:
                            lo = k
                    hi = lo + 1
                for k in range(lo, hi):
                    out_t[base + filled] = ct[k]
                    out_comp[base + filled] = cc[k]
                    out_tri[base + filled] = ctri[k]
                    out_energy[base + filled] = ce[k]
                    out_cos[base + filled] = ccos[k]
                    out_number[base + filled] = min(k + 1, 255)
                    out_count_of[base + filled] = min(nc, 255)
                    filled += 1
            count[local] = filled


@nb.njit(cache=True, parallel=True, fastmath=_FAST)
def finish_returns(first: int, n: int, slots: int, count: np.ndarray, out_t: np.ndarray, out_comp: np.ndarray,
                   out_tri: np.ndarray, out_energy: np.ndarray, out_cos: np.ndarray, out_number: np.ndarray,
                   out_count_of: np.ndarray, rays: np.ndarray, pulse: np.ndarray, origin: np.ndarray,
                   origin_step: int, key: np.uint64, range_sigma_m: float, range_ppm: float, geometric: bool, min_cos: float,
                   angle_sigma_rad: float, time0_s: float, pulse_period_s: float, intensity_ref_m: float,
                   station_id: int, component_label: np.ndarray, face_normal: np.ndarray, color: bool,
                   component_color: np.ndarray, color_noise: float, ambient: float, waviness_m: float,
                   waviness_wavelength_m: float, component_phase: np.ndarray,
                   xyz: np.ndarray, label: np.ndarray, component: np.ndarray, station: np.ndarray,
                   intensity: np.ndarray, time: np.ndarray, return_number: np.ndarray,
                   number_of_returns: np.ndarray, rgb: np.ndarray, source: np.ndarray) -> int:
    """Points of the returns ``gather_returns`` kept; returns how many rows were filled.

    Beams leave ``origin[r * origin_step]`` for ray r (a station's one origin: step 0; a moving
    platform's origin per ray: step 1); ``source`` receives each point's ray index.

    Range sigma = (range_sigma_m + range_ppm * 1e-6 * range) / max(|cos(incidence)|, min_cos) with
    ``geometric``, else range_sigma_m; angle noise as the paper path (one draw per pulse, shared by
    its returns). Waviness moves the range by -w / |cos| with w = waviness_m * sin(2 pi s /
    wavelength + phase_c), s the hit's coordinate along the surface's horizontal (or x) direction.
    Intensity = 65535 * energy * min(1, (ref / range)^2). Colour = style colour x (ambient + (1 -
    ambient) |cos|) x (1 + color_noise * N(0, 1)).
    """
    n_blocks = (n + _BLOCK - 1) // _BLOCK
    totals = np.zeros(n_blocks + 1, dtype=np.int64)
    for b in nb.prange(n_blocks):
        c = 0
        for local in range(b * _BLOCK, min(n, (b + 1) * _BLOCK)):
            c += count[local]
        totals[b + 1] = c
    for b in range(n_blocks):
        totals[b + 1] += totals[b]
    two_pi = 2.0 * math.pi
    for b in nb.prange(n_blocks):
        out = totals[b]
        for local in range(b * _BLOCK, min(n, (b + 1) * _BLOCK)):
            filled = count[local]
            if filled == 0:
                continue
            r_index = first + local
            p = pulse[r_index]
            o = r_index * origin_step
            ox, oy, oz = origin[o, 0], origin[o, 1], origin[o, 2]
            dx, dy, dz = float(rays[r_index, 3]), float(rays[r_index, 4]), float(rays[r_index, 5])
            n_range, n_az, n_el = pulse_normals(key, p)
            if angle_sigma_rad > 0.0:
                mx, my, mz = recorded_direction(dx, dy, dz, angle_sigma_rad * n_az, angle_sigma_rad * n_el)
            else:
                mx, my, mz = dx, dy, dz
            for k in range(filled):
                slot = local * slots + k
                t = out_t[slot]
                cosi = max(float(out_cos[slot]), min_cos)
                comp = out_comp[slot]
                tri = out_tri[slot]
                r = t
                if range_sigma_m > 0.0 or range_ppm > 0.0:
                    sigma = range_sigma_m
                    if geometric:
                        sigma = (range_sigma_m + range_ppm * 1e-6 * t) / cosi
                    z = n_range if k == 0 else draw_normal(key, p, _P_RANGE + k)
                    r += sigma * z
                if waviness_m > 0.0:
                    nx, ny, nz = face_normal[tri, 0], face_normal[tri, 1], face_normal[tri, 2]
                    px, py, pz = ox + t * dx, oy + t * dy, oz + t * dz
                    hn = math.sqrt(nx * nx + ny * ny)
                    if hn > 0.1:
                        along = (px * -ny + py * nx) / hn
                    else:
                        along = px
                    r -= waviness_m * math.sin(two_pi * along / waviness_wavelength_m + component_phase[comp]) / cosi
                xyz[out, 0] = ox + r * mx
                xyz[out, 1] = oy + r * my
                xyz[out, 2] = oz + r * mz
                component[out] = comp
                label[out] = component_label[comp]
                fall = min(1.0, intensity_ref_m / t)
                intensity[out] = np.uint16(min(65535.0, max(0.0, 65535.0 * out_energy[slot] * fall * fall + 0.5)))
                station[out] = station_id
                time[out] = time0_s + p * pulse_period_s
                return_number[out] = out_number[slot]
                number_of_returns[out] = out_count_of[slot]
                source[out] = r_index
                if color:
                    shade = (ambient + (1.0 - ambient) * float(out_cos[slot])) * (
                        1.0 + color_noise * draw_normal(key, p, _P_COLOR + k))
                    for channel in range(3):
                        value = 255.0 * component_color[comp, channel] * shade + 0.5
                        rgb[out, channel] = np.uint8(min(255.0, max(0.0, value)))
                out += 1
    return totals[n_blocks]


@dataclass(frozen=True)
class SensorTables:
    """What the sensor kernels read, built once per (scanner, sensor settings).

    Per component (C,): reflectance, label, colour (C, 3) float32 in 0..1, waviness phase. Per
    triangle (F,): unit normal (F, 3) float32, transparency (0 where glass is off) and transparent (bool).
    """

    reflectance: np.ndarray
    face_transparency: np.ndarray
    color: np.ndarray
    phase: np.ndarray
    face_normal: np.ndarray
    transparent_face: np.ndarray

"""Multi-station surveys: every station scanned in turn, merged into one stream of chunks.

Stations are scanned in id order and their chunks concatenated, so the merged cloud is the
stations' clouds one after another, each point keeping its station id. Station ``k``'s clock
starts where station ``k - 1``'s rotation ended.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

from bimscan.scan.noise import NoiseModel
from bimscan.scan.pattern import PulsePattern
from bimscan.scan.device import ScanSettings
from bimscan.scan.virtual_scanner import DEFAULT_CHUNK_PULSES, VirtualScanner
from bimscan.types import PointCloud, Station


def survey_pulses(stations: tuple[Station, ...], settings: ScanSettings, scanner: VirtualScanner) -> int:
    """Emitted pulses of the whole survey (for progress bars and size estimates)."""
    return PulsePattern.of(settings, scanner.scanner).count() * len(stations)


def run_survey(scanner: VirtualScanner, stations: tuple[Station, ...], settings: ScanSettings, *, noise: NoiseModel,
               seed: int, chunk_pulses: int = DEFAULT_CHUNK_PULSES,
               on_pulses: Callable[[int], None] | None = None, reuse_buffers: bool = False) -> Iterator[PointCloud]:
    """Stream the merged, labelled cloud of all stations.

    on_pulses(n) is called after each chunk with the number of pulses it covered (progress).
    reuse_buffers: chunks are overwritten by the next one (see VirtualScanner.scan_station).
    """
    duration = settings.duration_s()
    for index, station in enumerate(stations):
        yield from scanner.scan_station(station, settings, noise=noise, seed=seed, time0_s=index * duration,
                                        chunk_pulses=chunk_pulses, on_pulses=on_pulses, reuse_buffers=reuse_buffers)

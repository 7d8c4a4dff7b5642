"""The lidars a mobile platform carries, by name or file: multi-beam spinning lidars
(``scan.multibeam``) and Risley-prism lidars (``scan.risley``).

Both fire whole firing sequences of ``n_beams`` pulses every ``firing_cycle_us`` and number each
pulse's ``ring`` (``ring_of_beam``); they differ in where a pulse goes (a spinning column of
beams, or beams through turning prisms), which is the mobile scan's ray kernel's business
(``VirtualScanner.scan_pass``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from bimscan.errors import ConfigError
from bimscan.scan.device import MULTIBEAM_KIND, RISLEY_KIND, SCANNERS
from bimscan.scan.multibeam import LIDARS, MultiBeamScanner
from bimscan.scan.risley import RISLEY_SCANNERS, RisleyScanner
from bimscan.toml_files import build_dataclass, load_named

Lidar = MultiBeamScanner | RisleyScanner
MOBILE_LIDARS: dict[str, Lidar] = {**LIDARS, **RISLEY_SCANNERS}


def load_lidar(source: str | Path) -> Lidar:
    """A mobile platform's lidar by registry name or from a TOML file (the keys of
    scanners/velodyne_vlp16.toml with kind = "multibeam", or of scanners/livox_mid70.toml with
    kind = "risley")."""
    if isinstance(source, str) and source in SCANNERS:
        raise ConfigError(f"scanner {source!r} is a rotating-mirror TLS for the tripod (--platform tripod); a mobile "
                          f"platform carries a lidar: {', '.join(MOBILE_LIDARS)}")
    return load_named(source, MOBILE_LIDARS, kind="lidar", read=_read_lidar_file,
                      file='a scanner TOML file with kind = "multibeam" or "risley"')


def _read_lidar_file(table: dict[str, Any], path: Path) -> Lidar:
    kind = table.get("kind")
    if kind == MULTIBEAM_KIND:
        return build_dataclass(MultiBeamScanner, table, where=str(path))
    if kind == RISLEY_KIND:
        return build_dataclass(RisleyScanner, table, where=str(path))
    raise ConfigError(f"{path}: a mobile platform needs a lidar (kind = \"multibeam\" or \"risley\"); this file "
                      "describes a rotating-mirror TLS: use it with --platform tripod")

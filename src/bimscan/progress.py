"""Progress bars for long work, on stderr, quiet when stderr is not a terminal.

Set ``BIMSCAN_PROGRESS=1`` to force bars on (e.g. in CI logs) or ``0`` to force them off.
"""

from __future__ import annotations

import os
import sys
from typing import Any

from tqdm import tqdm


def progress_bar(*, total: float | None, desc: str, unit: str = "it", enabled: bool = True, **kwargs: Any) -> tqdm:
    """A tqdm bar on stderr; use as a context manager and call ``update(n)``."""
    setting = os.environ.get("BIMSCAN_PROGRESS", "")
    disable: bool | None = None if setting == "" else setting == "0"
    if not enabled:
        disable = True
    return tqdm(
        total=total, desc=desc, unit=unit, file=sys.stderr, disable=disable, dynamic_ncols=True,
        unit_scale=unit not in ("it", "unit", "scene", "station", "epoch"), leave=False, **kwargs,
    )

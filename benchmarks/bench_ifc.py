"""IFC loading throughput: components/s and triangles/s on the shared models, cold and cached.

Run: python benchmarks/bench_ifc.py [MODEL.ifc ...]   (default: ../shared/data/ifc/*.ifc)
Cold = parse with IfcOpenShell's geometry iterator on all cores; cached = the same call served
from the geometry cache (a fresh temporary cache folder each run).
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
DEFAULT = sorted((HERE.parent.parent / "shared" / "data" / "ifc").glob("*.ifc"))


def main(paths: list[Path]) -> None:
    os.environ["BIMSCAN_CACHE_DIR"] = tempfile.mkdtemp(prefix="bimscan-bench-cache-")
    from bimscan.pipeline import load_scene

    print(f"{'model':<24} {'comps':>6} {'tris':>8} {'cold s':>7} {'comp/s':>8} {'Mtri/s':>7} "
          f"{'cached s':>9} {'comp/s':>9} {'Mtri/s':>7} {'speed-up':>8}")
    for path in paths:
        start = time.perf_counter()
        scene = load_scene(path)
        cold = time.perf_counter() - start
        start = time.perf_counter()
        load_scene(path)
        cached = time.perf_counter() - start
        n, t = len(scene.components), scene.mesh.n_triangles
        print(f"{path.name:<24} {n:>6} {t:>8} {cold:>7.2f} {n / cold:>8.0f} {t / cold / 1e6:>7.3f} "
              f"{cached:>9.4f} {n / cached:>9.0f} {t / cached / 1e6:>7.2f} {cold / cached:>7.0f}x")
    print(f"threads: {os.cpu_count()}")


if __name__ == "__main__":
    main([Path(p) for p in sys.argv[1:]] or DEFAULT)

"""IFC loading throughput: components/s and triangles/s on the shared models, cold and cached,
and what the crash-proof worker process costs.

Run: python benchmarks/bench_ifc.py [--repeat N] [MODEL.ifc ...]   (default: ../shared/data/ifc/*.ifc)

- cold: ``load_scene`` as a command runs it: a fresh geometry worker process (start-up and
  imports included), IfcOpenShell's geometry iterator on all cores, the result sent back;
- in-process: the same parse (``bimscan.ifc.parse.parse_model``) called in this process, without
  the watchdog: the difference is the watchdog's cost;
- cached: the same ``load_scene`` served from the geometry cache (a fresh temporary cache folder).

Each figure is the median of ``--repeat`` runs, cold and in-process interleaved so that both see
the same machine load.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
DEFAULT = sorted((HERE.parent.parent / "shared" / "data" / "ifc").glob("*.ifc"))


def main(paths: list[Path], repeat: int) -> None:
    os.environ["BIMSCAN_CACHE_DIR"] = tempfile.mkdtemp(prefix="bimscan-bench-cache-")
    os.environ.setdefault("BIMSCAN_PROGRESS", "0")
    from bimscan.files import file_sha256
    from bimscan.ifc.parse import ParseRequest, parse_model
    from bimscan.ifc.watchdog import shutdown_workers
    from bimscan.pipeline import load_scene

    print(f"{'model':<24} {'comps':>6} {'tris':>8} {'cold s':>7} {'in-proc s':>9} {'watchdog':>8} {'comp/s':>7} "
          f"{'Mtri/s':>7} {'cached s':>9} {'speed-up':>8}")
    for path in paths:
        request = ParseRequest(path=str(path), name=str(path), file_sha256=file_sha256(path), threads=os.cpu_count() or 1)
        cold, inproc = [], []
        for _ in range(repeat):
            shutdown_workers()  # a command starts its own worker
            start = time.perf_counter()
            scene = load_scene(path, use_cache=False)
            cold.append(time.perf_counter() - start)
            start = time.perf_counter()
            parse_model(request)
            inproc.append(time.perf_counter() - start)
        load_scene(path)  # fills the cache
        start = time.perf_counter()
        load_scene(path)
        cached = time.perf_counter() - start
        c, p = statistics.median(cold), statistics.median(inproc)
        n, t = len(scene.components), scene.mesh.n_triangles
        print(f"{path.name:<24} {n:>6} {t:>8} {c:>7.2f} {p:>9.2f} {100 * (c / p - 1):>+7.0f}% {n / c:>7.0f} "
              f"{t / c / 1e6:>7.3f} {cached:>9.4f} {c / cached:>7.0f}x")
    print(f"threads: {os.cpu_count()}, repeats: {repeat}, load average: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("models", nargs="*", type=Path)
    parser.add_argument("--repeat", type=int, default=3)
    arguments = parser.parse_args()
    main(arguments.models or DEFAULT, arguments.repeat)
    sys.exit(0)

"""Run every benchmark script in turn; each writes its own files to results/.

Usage: ``.venv/bin/python scripts/bench_all.py [name ...]`` (default: all).
"""

from __future__ import annotations

import runpy
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
BENCHMARKS = (
    "bench_eigen", "bench_element_kernels", "bench_cubature", "bench_precompute",
    "bench_interpolation", "bench_table2", "bench_large_steps", "bench_live",
)


def main(names: list[str]) -> int:
    for name in names or BENCHMARKS:
        script = HERE / f"{name}.py"
        if not script.exists():
            print(f"bench_all: skipping {name} (not present)")
            continue
        started = time.perf_counter()
        print(f"bench_all: {name} ...", flush=True)
        runpy.run_path(str(script), run_name="__main__")
        print(f"bench_all: {name} done in {time.perf_counter() - started:.1f} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

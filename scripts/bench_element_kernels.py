"""Per-call time of the numpy element kernels on a cubature-sized element set.

Usage: ``.venv/bin/python scripts/bench_element_kernels.py [--elements 60]``; writes
``results/bench_element_kernels.json`` (median and spread in µs per call over
repeats, warm-up excluded, with the thread settings).
"""

from __future__ import annotations

import argparse
import timeit
from pathlib import Path

import numpy as np

from lbshape.elastic.element_kernels import ElementKernel
from lbshape.elastic.materials import MODELS, Material
from lbshape.geometry.primitives import structured_box
from lbshape.io.atomic import write_json_atomic
from lbshape.io.machine import machine_description

DEFAULT_OUT = Path(__file__).resolve().parents[1] / "results" / "bench_element_kernels.json"


def _microseconds(call, *, number: int, repeats: int) -> dict:
    call()  # warm-up
    times = np.array(timeit.repeat(call, number=number, repeat=repeats)) / number * 1e6
    return {
        "median_us": float(np.median(times)),
        "min_us": float(times.min()),
        "max_us": float(times.max()),
    }


def bench_element_kernels(
    *,
    n_elements: int = 60,
    number: int = 2000,
    repeats: int = 7,
    rng: np.random.Generator | None = None,
) -> dict:
    """Time energy, forces and forces_and_tangents of ``n_elements`` tetrahedra.

    Args:
        n_elements: elements per call (the cubature size s).
        number: calls per timing sample.
        repeats: timing samples (median and spread are reported).
        rng: generator for the displacements (seeded default).

    Returns:
        ``{"n_elements", "threads", "machine", "rows": [{"model", "method",
        "median_us", "min_us", "max_us"}, …]}``.
    """
    rng = np.random.default_rng(0) if rng is None else rng
    machine = machine_description()
    divisions = int(np.ceil((n_elements / 6) ** (1 / 3)))
    mesh = structured_box((0.2, 0.2, 0.2), (divisions,) * 3)
    tets = mesh.tets[rng.choice(mesh.n_tets, size=n_elements, replace=False)]
    ue = 0.01 * rng.normal(size=(n_elements, 4, 3))
    rows = []
    for model in MODELS:
        kernel = ElementKernel(mesh.points, tets, Material(model))
        for method in ("energy", "forces", "forces_and_tangents"):
            fn = getattr(kernel, method)
            timing = _microseconds(lambda fn=fn: fn(ue), number=number, repeats=repeats)
            rows.append({"model": model, "method": method, **timing})
    return {
        "n_elements": n_elements,
        "threads": machine["threads"],
        "machine": machine["cpu"],
        "rows": rows,
    }


def main(argv: list[str] | None = None) -> Path:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--elements", type=int, default=60)
    parser.add_argument("--number", type=int, default=2000)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("-o", "--out", type=Path, default=DEFAULT_OUT)
    args = parser.parse_args(argv)
    result = bench_element_kernels(
        n_elements=args.elements, number=args.number, repeats=args.repeats
    )
    for row in result["rows"]:
        print(f"{row['model']:>10} {row['method']:>20}: {row['median_us']:8.1f} µs")
    return write_json_atomic(args.out, result)


if __name__ == "__main__":
    main()

"""The full-space reference, former and fast path side by side (issue 38, item 1).

Usage: ``.venv/bin/python scripts/bench_full_reference.py [SCENE ...] [--steps N]
[--contact-steps N] [--repeats K] [--out-dir results]`` (default: every built-in scene of
:data:`SCENES` and the user-style tube built here, 100 steps, 1 repeat; scenes with
contact planes 400 steps, so that their runs hold their first impacts: the car meets the
wall at step 137, the Figure 4 bars the floor at step 289).

For each scene the former path (``linear_solver="lu-each-iteration"``: numpy assembly,
one SuperLU factorisation per Newton iteration, the general example energy) and the
fast one (``"reuse"``: compiled assembly, one Cholesky factorisation reused across Newton
iterations and steps with GMRES, the compiled block example energy) run the same steps
in one process, interleaved (the order alternates between repeats). Written (atomically):
``full_reference.md`` and ``full_reference.json``:

* ms per step (the record's per-step totals, mean and median; the first step, which
  factorises, counted; after a discarded 2-step warm-up run of each path, which loads or
  compiles the kernels) of both and their ratio;
* the floor ratio: a step's time over one assembly plus one factorisation of its own
  Newton matrix (at the run's last state; the fast path: compiled assembly and a fresh
  Cholesky with its ordering, the former path: numpy assembly and SuperLU);
* agreement: ``max_t ‖u − u_old‖_M / max_t ‖u_old‖_M`` over the run and, for a free body
  with contact planes, up to its first contact (the first state of the former run with a
  surface vertex behind a plane);
* factorisations and GMRES iterations of the fast path; the command, commit, date,
  machine and threads (:func:`lbshape.io.machine.machine_description`);
* the levers side by side on the scene's Newton matrix at rest (:func:`levers`):
  assembly numpy / compiled, SuperLU (two orderings) / CHOLMOD (with ordering, numeric
  only) factorisations and solves, one example-energy evaluation general / block.

The user-style scene: a 0.4 m hollow tube (outer radius 3 cm, wall 1 cm) from a gmsh
script written here, about 2.2k vertices, held at its top, under gravity and a ramped
torque, with two examples (twisted by ±0.8 rad).
"""

from __future__ import annotations

import os

if __name__ == "__main__":  # single-threaded BLAS for the timings, set before numpy loads
    for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, "1")

import argparse
import datetime
import functools
import logging
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path

import numpy as np

import lbshape.pipeline.simulate as simulate_module
from lbshape.dynamics.full import FullSpaceSimulator
from lbshape.dynamics.linear_solvers import factorise
from lbshape.io.atomic import write_json_atomic, write_text_atomic
from lbshape.io.machine import machine_description, threads_text
from lbshape.pipeline.precompute import precompute
from lbshape.scene import load_scene, scene_from_dict

log = logging.getLogger(__name__)

#: the built-in scenes of the benchmark
SCENES = ("bar-cuboid", "bar-cylinder", "cross", "car", "teddy-global", "teddy-local",
          "bar-s-cuboid", "bar-s-cylinder", "demo")
#: the user-style scene built by :func:`user_scene`
USER_SCENE = "user-tube"
#: the paths compared: the former one first
PATHS = ("lu-each-iteration", "reuse")

TUBE_SCRIPT = '''
import gmsh

DEFAULT_SIZE = 0.0085


def build(model, h):
    occ = model.occ
    outer = occ.addCylinder(0.0, 0.0, 0.0, 0.0, 0.0, 0.4, 0.03)
    inner = occ.addCylinder(0.0, 0.0, -0.01, 0.0, 0.0, 0.42, 0.02)
    body, _ = occ.cut([(3, outer)], [(3, inner)])
    occ.synchronize()
    top = model.getEntitiesInBoundingBox(-1, -1, 0.399, 1, 1, 0.401, dim=2)
    model.setPhysicalName(2, model.addPhysicalGroup(2, [t for _, t in top]), "top")
    model.setPhysicalName(3, model.addPhysicalGroup(3, [t for _, t in body]), "body")
    gmsh.option.setNumber("Mesh.MeshSizeMin", h)
    gmsh.option.setNumber("Mesh.MeshSizeMax", h)
'''

TUBE_SCENE = '''
name = "user-tube"
description = "A user's hollow tube (gmsh script), held at its top, twisted towards two examples."

[object]
shape = "tube.py"

[material]
model = "stvk"
young = 1.0e6
poisson = 0.3
density = 1000.0

[damping]
alpha = 0.5
beta = 0.005

[reduced]
m = 10
r = 30
s = 60

[examples]
stiffness = 3000.0

[[examples.pose]]
shape = "tube.py"
pose = "twist"
parameters = { angle = 0.8, axis = "z", anchor = "max" }

[[examples.pose]]
shape = "tube.py"
pose = "twist"
parameters = { angle = -0.8, axis = "z", anchor = "max" }

[fixed]
group = "top"

[[loads]]
type = "gravity"
vector = [0.0, 0.0, -9.81]

[[loads]]
type = "region_torque"
vector = [0.0, 0.0, 2.0]
region = "z < 0.001"
profile = "ramp"
start = 0.0
duration = 0.1

[simulation]
dt = 0.001
steps = 300
'''


def user_scene(folder: Path):
    """The user-style tube scene, its script written into ``folder``."""
    (folder / "tube.py").write_text(TUBE_SCRIPT)
    return scene_from_dict(tomllib.loads(TUBE_SCENE), name=USER_SCENE, base_dir=folder)


def simulator(scene, pre, path: str) -> FullSpaceSimulator:
    """The scene's full-space simulator (:func:`lbshape.pipeline.simulate.full_simulation`)
    on the linear-solver ``path``."""
    original = simulate_module.FullSpaceSimulator
    simulate_module.FullSpaceSimulator = functools.partial(original, linear_solver=path)
    try:
        return simulate_module.full_simulation(scene, pre)
    finally:
        simulate_module.FullSpaceSimulator = original


def first_contact(sim: FullSpaceSimulator, states: np.ndarray) -> int | None:
    """The index of the first state with a surface vertex behind a contact plane (None:
    no contact planes, or none reached)."""
    if sim.contact is None:
        return None
    return next((index for index, u in enumerate(states) if sim.contact.touches(u)), None)


def trajectory_difference(new: np.ndarray, old: np.ndarray, mass) -> float:
    """``max_t ‖u − u_old‖_M / max_t ‖u_old‖_M`` over the common states."""
    count = min(len(new), len(old))
    new, old = new[:count], old[:count]

    def norms(states):
        return np.sqrt(np.maximum(np.einsum("ti,ti->t", states, (mass @ states.T).T), 0.0))

    scale = norms(old).max()
    return float(norms(new - old).max() / scale) if scale > 0 else 0.0


def _seconds(function, repeats: int = 3) -> float:
    """Median wall time (s) of ``repeats`` calls."""
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        function()
        times.append(time.perf_counter() - started)
    return float(np.median(times))


def floor_ms(sim: FullSpaceSimulator, path: str) -> tuple[float, float]:
    """(assembly ms, factorisation ms) of the Newton matrix at the simulator's state."""
    x = np.array(sim.stepper.x)
    assemble = functools.partial(sim._force_and_tangent, x)
    _, K = assemble()
    if path == "reuse":
        solver = sim.stepper._linear_solver
        J = solver.newton_matrix(sim.stepper._newton_base, K)
        matrix = J if solver.symmetric else 0.5 * (J + J.T)

        def factor():
            factorise(matrix.tocsr(), symmetric=True)
    else:
        import scipy.sparse as sp
        import scipy.sparse.linalg as spla

        J = sim.stepper._newton_base + K

        def factor():
            spla.splu(sp.csc_matrix(J))
    return 1e3 * _seconds(assemble), 1e3 * _seconds(factor)


def run_path(scene, pre, path: str, steps: int) -> dict:
    """One run of ``steps`` steps on ``path``: timings, states, the floor."""
    sim = simulator(scene, pre, path)
    record = sim.run(steps)  # a failed step ends the record (stable False)
    out = {
        "path": path,
        "stable": bool(record.stable),
        "message": record.message,
        "steps": int(record.steps),
        "ms_per_step_mean": float(np.mean(record.t_total_ms)) if record.steps else None,
        "ms_per_step_median": float(np.median(record.t_total_ms)) if record.steps else None,
        "interp_ms_mean": float(np.mean(record.t_interp_ms)) if record.steps else None,
        "newton_iterations_mean": (float(np.mean(record.newton_iterations))
                                   if record.steps else None),
        "states": np.asarray(record.states),
        "sim": sim,
    }
    if path == "reuse":
        solver = sim.stepper._linear_solver
        out["factorisations"] = int(solver.factorisations)
        out["linear_solves"] = int(solver.solves)
        out["gmres_iterations_per_solve"] = (solver.inner_iterations / solver.solves
                                             if solver.solves else None)
    assembly, factor = floor_ms(sim, path)
    out["floor_assembly_ms"], out["floor_factorisation_ms"] = assembly, factor
    out["floor_ratio"] = (out["ms_per_step_mean"] / (assembly + factor)
                          if out["ms_per_step_mean"] else None)
    return out


def levers(scene, pre) -> dict:
    """The levers side by side on the scene's Newton matrix at rest (ms, median of 3):
    assembly (numpy, compiled), factorisation (SuperLU with COLAMD and with the
    MMD(Aᵀ + A) ordering, CHOLMOD with its ordering, CHOLMOD numeric only), one solve with
    each factor, and one example-energy evaluation (general, compiled block)."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    from lbshape.dynamics.linear_solvers import CholmodFactor

    old, new = simulator(scene, pre, PATHS[0]), simulator(scene, pre, PATHS[1])
    x = np.zeros(new.free_dofs.size)
    _, K = new._force_and_tangent(x)
    solver = new.stepper._linear_solver
    J = solver.newton_matrix(new.stepper._newton_base, K)
    sym = J if solver.symmetric else sp.csr_matrix(0.5 * (J + J.T))
    rhs = np.random.default_rng(0).normal(size=J.shape[0])
    out = {"dofs": int(J.shape[0]), "nnz": int(J.nnz)}
    out["assembly_numpy_ms"] = 1e3 * _seconds(lambda: old._force_and_tangent(x))
    out["assembly_compiled_ms"] = 1e3 * _seconds(lambda: new._force_and_tangent(x))
    csc = sp.csc_matrix(J)
    for name, spec in (("superlu_colamd", "COLAMD"), ("superlu_mmd_at_plus_a", "MMD_AT_PLUS_A")):
        out[f"{name}_factor_ms"] = 1e3 * _seconds(lambda spec=spec: spla.splu(csc,
                                                                           permc_spec=spec))
        lu = spla.splu(csc, permc_spec=spec)
        out[f"{name}_solve_ms"] = 1e3 * _seconds(lambda lu=lu: lu.solve(rhs), 5)
    out["cholmod_factor_ms"] = 1e3 * _seconds(lambda: CholmodFactor(sym).destroy())
    factor = CholmodFactor(sym)
    out["cholmod_numeric_refactor_ms"] = 1e3 * _seconds(lambda: factor.refactor(sym))
    out["cholmod_solve_ms"] = 1e3 * _seconds(lambda: factor.solve(rhs), 5)
    factor.destroy()
    if new.uses_examples and new._local is None:
        z = np.array(new._target_solver.offsets[0]) * 0.5
        for key, sim in (("example_energy_general_ms", old), ("example_energy_block_ms", new)):
            model = sim._target_solver.models[0]
            block = getattr(model, "_block", None)

            def evaluate(model=model, block=block):
                if block is not None:
                    block._last = None  # no kept evaluation: the full cost
                model.energy_force_and_tangent(z)
            out[key] = 1e3 * _seconds(evaluate)
    return out


def bench_scene(scene, steps: int, repeats: int) -> dict:
    """Both paths on one scene, interleaved over ``repeats``; the fastest repeat of each
    is reported (agreement from the last pair)."""
    pre = precompute(scene)
    lever_times = levers(scene, pre)
    for path in PATHS:  # warm-up: compiled kernels loaded (or compiled), caches filled
        simulator(scene, pre, path).run(2)
    best: dict[str, dict] = {}
    runs: dict[str, dict] = {}
    for repeat in range(repeats):
        order = PATHS if repeat % 2 == 0 else PATHS[::-1]
        for path in order:
            runs[path] = run_path(scene, pre, path, steps)
            log.info("%s %s: %.2f ms/step", scene.name, path, runs[path]["ms_per_step_mean"]
                     or float("nan"))
            kept = best.get(path)
            if kept is None or (runs[path]["ms_per_step_mean"] or np.inf) < (
                    kept["ms_per_step_mean"] or np.inf):
                best[path] = runs[path]
    old, new = runs[PATHS[0]], runs[PATHS[1]]
    mass = new["sim"].mass
    contact = first_contact(old["sim"], old["states"])
    row = {
        "scene": scene.name,
        "vertices": int(pre.mesh.n_vertices),
        "dofs": int(new["sim"].free_dofs.size),
        "steps": steps,
        "dt": float(scene.simulation.dt),
        "free_body": bool(pre.fixed_vertices.size == 0),
        "agreement": trajectory_difference(new["states"], old["states"], mass),
        "levers": lever_times,
        "first_contact_state": contact,
        "agreement_to_first_contact": (
            trajectory_difference(new["states"][:contact + 1], old["states"][:contact + 1],
                                  mass) if contact else None),
    }
    for path, key in zip(PATHS, ("old", "new"), strict=True):
        run = best[path]
        row[key] = {k: v for k, v in run.items() if k not in ("states", "sim")}
    if row["old"]["ms_per_step_mean"] and row["new"]["ms_per_step_mean"]:
        row["speedup"] = row["old"]["ms_per_step_mean"] / row["new"]["ms_per_step_mean"]
    return row


def _commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                              check=True, cwd=Path(__file__).resolve().parent).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def _number(value, digits: int = 1) -> str:
    return "—" if value is None else f"{value:.{digits}f}"


def _lever_row(row: dict) -> str:
    lev = row["levers"]
    energy = (f"{_number(lev['example_energy_general_ms'], 2)} / "
              f"{_number(lev['example_energy_block_ms'], 2)}"
              if "example_energy_block_ms" in lev else "—")
    return (f"| {row['scene']} | {lev['dofs']} | {lev['nnz']} | "
            f"{_number(lev['assembly_numpy_ms'], 2)} / {_number(lev['assembly_compiled_ms'], 2)}"
            f" | {_number(lev['superlu_colamd_factor_ms'], 2)} / "
            f"{_number(lev['superlu_mmd_at_plus_a_factor_ms'], 2)} / "
            f"{_number(lev['cholmod_factor_ms'], 2)} / "
            f"{_number(lev['cholmod_numeric_refactor_ms'], 2)} | "
            f"{_number(lev['superlu_colamd_solve_ms'], 3)} / "
            f"{_number(lev['superlu_mmd_at_plus_a_solve_ms'], 3)} / "
            f"{_number(lev['cholmod_solve_ms'], 3)} | {energy} |")


def _contact_text(row: dict) -> str:
    """The agreement up to the first contact, or why there is none."""
    if row["first_contact_state"] == 0:
        return "in contact from the start"
    if row["agreement_to_first_contact"] is None:
        return "—"
    return f"{row['agreement_to_first_contact']:.1e} (state {row['first_contact_state']})"


def markdown(payload: dict) -> str:
    lines = [
        "# Full-space reference: former and fast path",
        "",
        "Former: numpy assembly, a SuperLU factorisation per Newton iteration, the general "
        "example energy. Fast: compiled assembly, one Cholesky factorisation (CHOLMOD) "
        "reused across Newton iterations and steps as GMRES's preconditioner, each update "
        f"solved to a relative residual of {payload['linear_rtol']:g} or to a tenth of the "
        "step's Newton tolerance where that is larger (a free body's: or to a tenth of the "
        "last update's contraction of the residual, at most 1e-3; refactorised when GMRES "
        "slows), the compiled block example energy; a modified Newton (the residual test on "
        "the force alone, the tangent kept while each update lowers the residual 10-fold, "
        "evaluated afresh when one does not): across steps with its factor on fixed scenes "
        "without contact or friction and on free bodies in flight (turned with the body, "
        "kept while each update lowers the residual 100-fold), else taken afresh with each "
        "step's first residual; a free body's tangent with its damping's turn with the spin "
        "and the contact's with the facing areas' change. Same Newton residual test. Both in "
        "one process, interleaved.",
        "",
        f"Command: `{payload['command']}`  ",
        f"Commit: `{payload['commit']}`, {payload['date']}  ",
        f"Machine: {payload['machine']['cpu']}, {payload['machine']['cores']} cores, "
        f"threads {threads_text(payload['machine'])}, load "
        f"{payload['machine']['load_average']}",
        "",
        "| scene | vertices | steps | former ms/step | fast ms/step | speed-up | "
        "fast floor ratio | former floor ratio | factorisations | GMRES it./solve | "
        "Newton it./step former / fast | agreement | to first contact |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for row in payload["scenes"]:
        old, new = row["old"], row["new"]
        lines.append(
            f"| {row['scene']} | {row['vertices']} | {row['steps']} | "
            f"{_number(old['ms_per_step_mean'])} | {_number(new['ms_per_step_mean'], 2)} | "
            f"{_number(row.get('speedup'))}× | {_number(new['floor_ratio'], 2)} | "
            f"{_number(old['floor_ratio'], 2)} | {new.get('factorisations', '—')} | "
            f"{_number(new.get('gmres_iterations_per_solve'))} | "
            f"{_number(old['newton_iterations_mean'], 2)} / "
            f"{_number(new['newton_iterations_mean'], 2)} | {row['agreement']:.1e} | "
            + _contact_text(row) + " |")
    lines += [
        "",
        "Levers on each scene's Newton matrix at rest (ms, median of 3): assembly numpy / "
        "compiled; factorisation SuperLU (COLAMD) / SuperLU (MMD(Aᵀ+A)) / CHOLMOD / "
        "CHOLMOD numeric only; one solve SuperLU (COLAMD) / SuperLU (MMD) / CHOLMOD; one "
        "example-energy evaluation general / compiled block (global examples).",
        "",
        "| scene | dofs | nnz | assembly | factorisation | solve | example energy |",
        "|---|---:|---:|---|---|---|---|",
        *[_lever_row(row) for row in payload["scenes"]],
        "",
        "ms/step: mean of the per-step totals (example target included). Floor ratio: a "
        "step's time over one assembly plus one factorisation of its own Newton matrix "
        "(fast: compiled assembly + fresh Cholesky with ordering; former: numpy assembly "
        "+ SuperLU). Agreement: `max_t ‖u − u_old‖_M / max_t ‖u_old‖_M` (issue 38: ≤ 1e-6).",
        "",
    ]
    unstable = [f"{row['scene']} ({key}: {row[key]['message']})" for row in payload["scenes"]
                for key in ("old", "new") if not row[key]["stable"]]
    if unstable:
        lines += ["Stopped runs: " + "; ".join(unstable), ""]
    return "\n".join(lines)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenes", nargs="*", default=[*SCENES, USER_SCENE],
                        help=f"built-in scenes and/or {USER_SCENE} (default: all)")
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--contact-steps", type=int, default=400,
                        help="steps of scenes with contact planes (their first impacts)")
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--out-dir", type=Path, default=Path("results"))
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    from lbshape.dynamics.linear_solvers import LINEAR_RTOL

    logging.basicConfig(level=logging.INFO, format="%(message)s")
    args = parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        for name in args.scenes:
            scene = user_scene(Path(folder)) if name == USER_SCENE else load_scene(name)
            steps = args.contact_steps if scene.planes else args.steps
            rows.append(bench_scene(scene, steps, args.repeats))
    payload = {
        "command": " ".join([Path(sys.argv[0]).name, *(argv if argv is not None
                                                        else sys.argv[1:])]),
        "commit": _commit(),
        "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "machine": machine_description(),
        "linear_rtol": LINEAR_RTOL,
        "scenes": rows,
    }
    args.out_dir.mkdir(parents=True, exist_ok=True)
    write_json_atomic(args.out_dir / "full_reference.json", payload)
    write_text_atomic(args.out_dir / "full_reference.md", markdown(payload))
    print(markdown(payload))
    return 0


if __name__ == "__main__":
    sys.exit(main())

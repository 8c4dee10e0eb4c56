"""Where does the reduced method's error against the full-space reference come from?

For each scene the reduced trajectory's error against ``full``
(``max_t ‖u − u_full‖_M / max_t ‖u_full‖_M``, as in ``lbshape bench``) is split into:

* **subspace** — the full trajectory's best M-orthogonal projection onto span U
  (free bodies: the body-frame deformation after the best rigid fit), the error no
  reduced dynamics in this basis can beat;
* **Newton** — the reduced run with converged Newton steps instead of the real-time
  single update (fixed objects; free bodies always converge);
* **cubature** — the reduced run with the exact reduced force (every element,
  weight 1) against the run with the cubature;
* **examples** — the same errors with the example force switched off in both
  methods (k_ex = 0): if the error drops, the example forces act differently in the
  reduced and full methods;
* **local example forces** (scenes with regions) — per region, the full reference's
  example force at the full trajectory's states against the reduced method's at the
  projected state: the projection ``Uᵀ f_R`` (consistency of the two methods, which
  must agree for a state in span U), and the share of ``M⁻¹ f_R`` outside span U.

Writes ``results/accuracy_diagnosis.json`` (merged per scene, so scenes can be run
one at a time) and ``results/accuracy_diagnosis.md``.

Usage: ``python scripts/diagnose_accuracy.py [--scenes cross car ...] [--label NAME]``
(``--label`` names the variant of the code being measured, e.g. ``before`` / ``after``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time

import numpy as np

from lbshape.analysis.norms import m_norms, trajectory_error
from lbshape.dynamics.engine import NewtonSettings
from lbshape.dynamics.rigid_frame import best_rigid_frame
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.io.atomic import write_json_atomic, write_text_atomic
from lbshape.io.paths import RESULTS_DIR
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulate import (
    example_stiffness,
    reduced_simulation,
    run_full_space,
)
from lbshape.scene import load_scene
from lbshape.scene.variants import without_examples
from lbshape.shapespace.interpolation import resolve_route
from lbshape.shapespace.local_driver import local_example_driver, local_route
from lbshape.shapespace.local_full_force import FullSpaceLocalForce
from lbshape.shapespace.local_space import LocalShapeSpace

SCENES = ("bar-cuboid", "cross", "car", "teddy-global", "teddy-local")
STRIDE = 5
#: relative Newton residual of the converged variants
CONVERGED_RTOL = 1e-10
CONVERGED_NEWTON = NewtonSettings(CONVERGED_RTOL, 20)
JSON_PATH = RESULTS_DIR / "accuracy_diagnosis.json"
MD_PATH = RESULTS_DIR / "accuracy_diagnosis.md"


def _flat(u: np.ndarray) -> np.ndarray:
    return np.asarray(u, dtype=float).reshape(u.shape[0], -1)


def subspace_error(u_full: np.ndarray, U: np.ndarray, mass, *, free: bool,
                   points: np.ndarray) -> float:
    """``max_t ‖u_full − P u_full‖_M / max_t ‖u_full‖_M``, P the M-orthogonal projection
    on span U (free bodies: on the best rigid motion plus span U in its frame)."""
    flat = _flat(u_full)
    if not free:
        projected = (U @ (U.T @ (mass @ flat.T))).T
    else:
        scalar = mass[0::3, 0::3].tocsr()
        n = points.shape[0]
        projected = np.empty_like(flat)
        for i, u in enumerate(flat):
            x = points + u.reshape(n, 3)
            center, R, body = best_rigid_frame(scalar, points, x)
            Xbar = (x - center) @ R - body  # rest shape about its centre of mass
            b = body.reshape(-1)
            b_proj = (U @ (U.T @ (mass @ b))).reshape(n, 3)
            projected[i] = (center + (Xbar + b_proj) @ R.T - points).reshape(-1)
    return float(m_norms(flat - projected, mass).max() / m_norms(flat, mass).max())


def error(u: np.ndarray | None, u_full: np.ndarray | None, mass) -> float | None:
    """The trajectory error; None when either run stopped."""
    if u is None or u_full is None:
        return None
    return trajectory_error(_flat(u), _flat(u_full), mass)


def centre_velocity(u: np.ndarray, times: np.ndarray, points: np.ndarray, mass) -> np.ndarray:
    """(k-1, 3) centre-of-mass velocity (m/s) by differences of the sampled states."""
    weights = np.asarray(mass[0::3, 0::3].sum(axis=1)).ravel()
    centres = np.einsum("n,tnc->tc", weights, points[None] + np.asarray(u).reshape(
        u.shape[0], -1, 3)) / weights.sum()
    return np.diff(centres, axis=0) / np.diff(times)[:, None]


def _region_space(space: LocalShapeSpace, index: int, U: np.ndarray, mesh, rho) -> LocalShapeSpace:
    region = space.regions[index]
    sub = region.submesh(mesh)
    rows = (3 * region.vertices[:, None] + np.arange(3)).ravel()
    U_R = U[rows]
    spring = U_R.T @ (mass_matrix(sub, rho) @ U_R)
    return LocalShapeSpace((region,), 0.5 * (spring + spring.T), space.covered, {})


def local_force_comparison(scene, pre, u_full: np.ndarray, mass) -> dict:
    """Per region: full vs reduced local example force along the full trajectory."""
    k_ex = example_stiffness(scene, pre)
    route = local_route(resolve_route(scene.reduced.interpolation, scene.material.model),
                        pre.material)
    U, rho = pre.U, float(pre.material.density)
    lumped = np.asarray(mass.sum(axis=1)).ravel()
    out = {}
    flat = _flat(u_full)
    samples = flat[:: max(1, flat.shape[0] // 20)][1:]
    for index, region in enumerate(pre.local.regions):
        space = _region_space(pre.local, index, U, pre.mesh, rho)
        full = FullSpaceLocalForce(pre.mesh, pre.material, space)
        driver = local_example_driver(pre.mesh, pre.material, space, route=route)
        consistency, at_full, outside, weight_gap = [], [], [], []
        for u in samples:
            q = U.T @ (mass @ u)
            u_in = U @ q
            f_in = k_ex * (full.pull(u_in) - full.mass @ u_in)
            w_full_in = full.weights[region.name]
            f_red = k_ex * (driver.target(q).q_target - space.spring @ q)
            w_red = driver.region_weights(q)[region.name]
            ref = np.linalg.norm(U.T @ f_in) or 1.0
            consistency.append(float(np.linalg.norm(U.T @ f_in - f_red) / ref))
            weight_gap.append(float(np.abs(w_full_in - w_red).max()))
            f_u = k_ex * (full.pull(u) - full.mass @ u)
            ref_u = np.linalg.norm(U.T @ f_u) or 1.0
            at_full.append(float(np.linalg.norm(U.T @ f_u - f_red) / ref_u))
            # share of the force's displacement (lumped M⁻¹ f) outside span U
            a = f_u / lumped
            a_norm = float(np.sqrt(a @ (mass @ a))) or 1.0
            rest = a - U @ (U.T @ (mass @ a))
            outside.append(float(np.sqrt(rest @ (mass @ rest)) / a_norm))
        out[region.name] = {
            "projected_state_force_gap": max(consistency),
            "projected_state_weight_gap": max(weight_gap),
            "full_state_force_gap": max(at_full),
            "force_outside_span_U": float(np.median(outside)),
        }
    return out


def diagnose(name: str) -> dict:
    scene = load_scene(name)
    pre = precompute(scene)
    mass = mass_matrix(pre.mesh, pre.material.density)
    steps = scene.simulation.steps
    free = scene.is_free
    result: dict = {"scene": name, "steps": steps, "r": pre.r,
                    "s": int(pre.elastic.cubature_elements.size), "n_vertices": pre.mesh.n_vertices}
    started = time.perf_counter()

    stops: dict[str, str] = {}

    def reduced(sc, model=pre, what="reduced", **kw):
        """(displacements, times); a run that stopped gives (None, None), its message kept."""
        record = reduced_simulation(sc, model, **kw).run(steps, stride=STRIDE)
        if not record.stable:
            stops[what] = record.message
            return None, None
        return record.displacements(pre.U), record.times

    cubature = dataclasses.replace(pre, elastic=dataclasses.replace(
        pre.elastic, force_model="cubature"))  # the trained cubature

    def full(sc):
        record = run_full_space(sc, pre, steps=steps, stride=STRIDE)
        if not record.stable:
            raise RuntimeError(f"{name}: full run stopped: {record.message}")
        return record.displacements(), record.times

    has_examples = example_stiffness(scene, pre) > 0
    variants = [("examples", scene)] + ([("no_examples", without_examples(scene))]
                                        if has_examples else [])
    for label, sc in variants:
        stops.clear()
        u_full, times = full(sc)
        u_red, _ = reduced(sc)
        row = {"subspace": subspace_error(u_full, pre.U, mass, free=free,
                                          points=pre.mesh.points),
               "reduced": error(u_red, u_full, mass)}
        if not free:
            u_conv, _ = reduced(sc, what="converged", newton=CONVERGED_NEWTON)
            row["reduced_converged_newton"] = error(u_conv, u_full, mass)
            u_exact, _ = reduced(sc, what="exact forces", newton=CONVERGED_NEWTON,
                                 exact_forces=True)
        else:
            u_exact, _ = reduced(sc, what="exact forces", exact_forces=True)
        u_cub, _ = reduced(sc, model=cubature, what="cubature")
        row["reduced_exact_forces"] = error(u_exact, u_full, mass)
        row["reduced_cubature"] = error(u_cub, u_full, mass)
        row["cubature_vs_exact"] = error(u_cub, u_exact, mass)
        if stops:
            row["stopped"] = dict(stops)
        if free and u_red is not None:
            v_full = centre_velocity(u_full, times, pre.mesh.points, mass)
            v_red = centre_velocity(u_red, times, pre.mesh.points, mass)
            row["final_centre_velocity_full"] = v_full[-1].tolist()
            row["final_centre_velocity_reduced"] = v_red[-1].tolist()
            row["min_x_velocity_full"] = float(v_full[:, 0].min())
            row["min_x_velocity_reduced"] = float(v_red[:, 0].min())
        if label == "examples" and pre.has_local_examples and has_examples:
            row["local_forces"] = local_force_comparison(scene, pre, u_full, mass)
        result[label] = row
    result["seconds"] = time.perf_counter() - started
    return result


def _pct(value) -> str:
    return "–" if value is None else f"{100 * value:.1f} %"


def markdown(payload: dict) -> str:
    lines = [
        "# Reduced vs full: where the error comes from",
        "",
        "Produced by `scripts/diagnose_accuracy.py`. Errors are "
        "`max_t ‖u − u_ref‖_M / max_t ‖u_ref‖_M` over the scene's steps (states every "
        f"{STRIDE} steps). *subspace*: the full trajectory's best M-orthogonal projection "
        "onto span U (free body: after the best rigid fit); *reduced*: the real-time "
        "reduced run as it ships (its force model, Newton to the real-time residual "
        "tolerance); *converged*: Newton to a relative residual of 1e-10; *exact forces*: "
        "every element with weight 1 (converged Newton); *cubature*: the reduced run with "
        "the trained cubature as its force; *cubature vs exact*: the cubature run against "
        "the exact-force run. Variants measured before the cubature column existed show "
        "'–' there and their *reduced* run used the cubature. *no examples*: k_ex = 0 in "
        "both methods.",
        "",
    ]
    for label, variant in payload.get("variants", {}).items():
        if "scenes" not in variant:
            continue
        lines += [f"## Code variant: {label}", "", variant.get("note", ""), "",
                  "| scene | examples | subspace | reduced | converged | exact forces | "
                  "cubature | cubature vs exact |", "|---|---|---|---|---|---|---|---|"]
        for name, res in variant["scenes"].items():
            for key in ("examples", "no_examples"):
                row = res.get(key)
                if row is None:
                    continue
                lines.append(
                    f"| {name} | {'yes' if key == 'examples' else 'no'} | "
                    f"{_pct(row['subspace'])} | {_pct(row['reduced'])} | "
                    f"{_pct(row.get('reduced_converged_newton'))} | "
                    f"{_pct(row['reduced_exact_forces'])} | "
                    f"{_pct(row.get('reduced_cubature'))} | {_pct(row['cubature_vs_exact'])} |")
        lines.append("")
        for name, res in variant["scenes"].items():
            for key in ("examples", "no_examples"):
                for what, message in res.get(key, {}).get("stopped", {}).items():
                    lines += [f"{name} ({key.replace('_', ' ')}): the {what} run stopped "
                              f"('–' in the table): {message}", ""]
        for name, res in variant["scenes"].items():
            row = res.get("examples", {})
            if "local_forces" in row:
                lines += [f"Local example forces, {name} (along the full trajectory, 20 "
                          "samples; gaps are maxima, relative to ‖Uᵀ f_full‖):", "",
                          "| region | force gap at U-projected state | weight gap | "
                          "force gap at full state | median share of M⁻¹f outside span U |",
                          "|---|---|---|---|---|"]
                for region, d in row["local_forces"].items():
                    lines.append(
                        f"| {region} | {d['projected_state_force_gap']:.2e} | "
                        f"{d['projected_state_weight_gap']:.2e} | "
                        f"{_pct(d['full_state_force_gap'])} | "
                        f"{_pct(d['force_outside_span_U'])} |")
                lines.append("")
            if "final_centre_velocity_full" in row:
                lines += [f"Free body {name}: most negative centre-of-mass x velocity "
                          f"(rebound off the wall) full {row['min_x_velocity_full']:.2f} m/s, "
                          f"reduced {row['min_x_velocity_reduced']:.2f} m/s; final centre "
                          f"velocity full {np.round(row['final_centre_velocity_full'], 2)}, "
                          f"reduced {np.round(row['final_centre_velocity_reduced'], 2)} m/s.",
                          ""]
    variants = payload.get("variants", {})
    if "before" in variants and "after" in variants:
        lines += ["## Before → after (error of the real-time reduced run against full, with "
                  "examples; in parentheses the subspace error)", "",
                  "| scene | before | after |", "|---|---|---|"]
        for name, res in variants["after"]["scenes"].items():
            old = variants["before"]["scenes"].get(name)
            if old is None or "examples" not in res:
                continue
            lines.append(f"| {name} | {_pct(old['examples']['reduced'])} "
                         f"({_pct(old['examples']['subspace'])}) | "
                         f"{_pct(res['examples']['reduced'])} "
                         f"({_pct(res['examples']['subspace'])}) |")
        lines.append("")
    lines += payload.get("conclusions", [])
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=list(SCENES))
    parser.add_argument("--label", default="current")
    parser.add_argument("--note", default="")
    args = parser.parse_args()
    for name in args.scenes:
        res = diagnose(name)
        print(json.dumps(res, indent=1), flush=True)
        # re-read: other runs (other scenes or variants) may have written meanwhile
        payload = json.loads(JSON_PATH.read_text()) if JSON_PATH.exists() else {}
        variant = payload.setdefault("variants", {}).setdefault(args.label, {"scenes": {}})
        if args.note:
            variant["note"] = args.note
        variant["scenes"][name] = res
        write_json_atomic(JSON_PATH, payload)
        write_text_atomic(MD_PATH, markdown(payload))


if __name__ == "__main__":
    main()


"""Judge a hierarchy by what it is for: a multigrid solve.

The cell-centred two-point-flux finite-volume Poisson matrix on the fine mesh (the piecewise-constant
analogue of agglomeration-based DG multigrid), homogeneous Dirichlet boundary, right-hand side = cell
measures. The hierarchy's levels go into pyamg as predefined aggregates (unsmoothed aggregation:
piecewise constants on the agglomerates; smoothed: one Jacobi step on them), a V-cycle preconditions
CG down to a relative residual of 1e-8; pyamg's own smoothed aggregation on the same matrix is the
baseline. Reported: iterations, operator complexity, setup and solve time.
"""

from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp

from models.errors import ParameterError
from models.mesh.celldata import CellData
from models.mesh.container import Mesh

TOL = 1e-8
MAXITER = 500


def parse_kappa(text: str | None, dim: int | None = None) -> np.ndarray | None:
    """'kx,ky[,kz]' -> the diagonal of the diffusion tensor (positive, finite); None stays None."""
    if text is None:
        return None
    try:
        k = np.array([float(v) for v in str(text).split(",")], dtype=np.float64)
    except ValueError:
        raise ParameterError(f"kappa must be comma-separated numbers kx,ky[,kz], got {text!r}") from None
    if k.size not in (2, 3) or not np.all(np.isfinite(k)) or not np.all(k > 0):
        raise ParameterError(f"kappa must be two or three positive numbers kx,ky[,kz], got {text!r}")
    if dim is not None and k.size != dim:
        raise ParameterError(f"kappa has {k.size} values but the mesh is {dim}D: give one per axis")
    return k


def _directional(v: np.ndarray, kappa: np.ndarray | None) -> np.ndarray:
    """v_hat^T K v_hat for the rows v (K = diag(kappa)); 1 without kappa."""
    if kappa is None:
        return np.ones(v.shape[0])
    sq = v * v
    return (sq @ kappa) / np.maximum(sq.sum(axis=1), 1e-300)


def tpfa_poisson(
    mesh: Mesh, data: CellData, kappa: np.ndarray | None = None
) -> tuple[sp.csr_matrix, np.ndarray]:
    """(A, b): two-point flux -div(K grad) on the cells; transmissibility |f| k_d / distance between
    the centroids (interior faces) or between the centroid and the face centre (boundary faces,
    u = 0), where k_d = d^T K d / |d|^2 along that connecting vector d (K = diag(kappa), identity
    without; exact on K-orthogonal meshes such as axis-aligned boundary layers)."""
    from models.partition.rtree_strength import tpfa_boundary

    g = data.graph
    n = g.n
    c = data.centroids
    if kappa is not None:
        kappa = np.asarray(kappa, dtype=np.float64)
        if kappa.size != c.shape[1]:
            raise ParameterError(
                f"kappa has {kappa.size} values but the mesh is {c.shape[1]}D: give one per axis"
            )
    rows = np.repeat(np.arange(n), np.diff(g.indptr))
    dv = c[rows] - c[g.indices]
    d = np.linalg.norm(dv, axis=1)
    t = g.weights * _directional(dv, kappa) / np.maximum(d, 1e-300)
    owner, tb = tpfa_boundary(mesh, data, kappa)
    diag = np.bincount(rows, weights=t, minlength=n) + np.bincount(owner, weights=tb, minlength=n)
    A = sp.csr_matrix((-t, g.indices, g.indptr), shape=(n, n)) + sp.diags(diag)
    return A.tocsr(), np.asarray(data.measures, dtype=np.float64).copy()


def _solve(ml, b: np.ndarray) -> dict:
    res: list[float] = []
    t = time.perf_counter()
    x = ml.solve(b, tol=TOL, accel="cg", maxiter=MAXITER, residuals=res)
    t_solve = time.perf_counter() - t
    return {
        "iterations": len(res) - 1,
        "solve_time": t_solve,
        "converged": bool(res and res[-1] <= TOL * res[0]),
        "final_relative_residual": float(res[-1] / res[0]) if res and res[0] > 0 else 0.0,
        "x": x,
    }


def with_levels(A: sp.csr_matrix, b: np.ndarray, ops_fine_to_coarse: list, smooth: bool) -> dict:
    """PCG with a V-cycle on our aggregates (ops: fine cells -> finest level, then each next level)."""
    import pyamg

    t = time.perf_counter()
    ml = pyamg.smoothed_aggregation_solver(
        A,
        aggregate=[("predefined", {"AggOp": P.tocsr()}) for P in ops_fine_to_coarse],
        smooth=("jacobi", {"omega": 4.0 / 3.0}) if smooth else None,
        max_levels=len(ops_fine_to_coarse) + 1,
        max_coarse=1,
    )
    setup = time.perf_counter() - t
    out = _solve(ml, b)
    return {
        "setup_time": setup,
        "operator_complexity": float(ml.operator_complexity()),
        "levels": len(ml.levels),
        **out,
    }


def pyamg_sa(A: sp.csr_matrix, b: np.ndarray, smooth: bool = True) -> dict:
    """pyamg's standard aggregation as the baseline: its defaults (smoothed aggregation), or with
    smooth=False its unsmoothed aggregation (the same aggregates, piecewise-constant prolongation)."""
    import pyamg

    t = time.perf_counter()
    ml = pyamg.smoothed_aggregation_solver(A) if smooth else pyamg.smoothed_aggregation_solver(A, smooth=None)
    setup = time.perf_counter() - t
    out = _solve(ml, b)
    return {
        "setup_time": setup,
        "operator_complexity": float(ml.operator_complexity()),
        "levels": len(ml.levels),
        "sizes": [int(lv.A.shape[0]) for lv in ml.levels],
        **out,
    }


def _one_blas_thread():
    """The four solves with one BLAS thread: pyamg's work is sparse, OpenBLAS's threads only
    contended for the cores (an outside sweep: 2-3x the wall time and 3.6x the CPU on 10^5 cells, and
    setup or solve times that moved 10x between two runs), so the timings reported are the solvers'."""
    import contextlib

    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # (scikit-learn's dependency: there with it)
        return contextlib.nullcontext()
    return threadpool_limits(limits=1, user_api="blas")


def mgcheck(mesh: Mesh, data: CellData, levels: list[np.ndarray], kappa: np.ndarray | None = None) -> dict:
    """Unsmoothed and smoothed aggregation on our levels (coarsest first, as written by
    models.hierarchy.nested) beside pyamg's smoothed aggregation, on the TPFA Poisson problem
    (kappa: the diagonal of an anisotropic diffusion tensor, see tpfa_poisson)."""
    from models.hierarchy.nested import aggregation_operators, is_nested

    if not levels:
        raise ParameterError("the hierarchy has no levels")
    if any(np.asarray(lv).size != mesh.n_cells for lv in levels):
        raise ParameterError("the hierarchy's labels do not match the mesh (different number of cells)")
    if not is_nested(levels):
        raise ParameterError(
            "the levels are not nested: every element must lie inside one element of the coarser level"
        )
    A, b = tpfa_poisson(mesh, data, kappa)
    ops = list(reversed(aggregation_operators(levels, mesh.n_cells)))
    with _one_blas_thread():
        base_un = pyamg_sa(A, b, smooth=False)
        base = pyamg_sa(A, b)
        un = with_levels(A, b, ops, smooth=False)
        sm = with_levels(A, b, ops, smooth=True)
    for r in (base, base_un, un, sm):
        r.pop("x")
    ratio = {  # ours against pyamg's standard aggregation, unsmoothed against unsmoothed, smoothed against smoothed
        "unsmoothed_iterations_vs_pyamg": _iterations_ratio(un, base_un),
        "unsmoothed_complexity_vs_pyamg": un["operator_complexity"] / base_un["operator_complexity"],
        "smoothed_iterations_vs_pyamg": _iterations_ratio(sm, base),
        "smoothed_complexity_vs_pyamg": sm["operator_complexity"] / base["operator_complexity"],
    }
    solves = {"unsmoothed": un, "smoothed": sm, "pyamg_ua": base_un, "pyamg_sa": base}
    return {
        "problem": "TPFA Poisson, Dirichlet boundary, rhs = cell measures; PCG, V-cycle, tol 1e-8"
        + ("" if kappa is None else f"; kappa = diag({', '.join(f'{v:g}' for v in kappa)})"),
        "kappa": None if kappa is None else [float(v) for v in kappa],
        "unknowns": int(A.shape[0]),
        "level_sizes": [int(lv.max()) + 1 for lv in reversed(levels)],
        "unsmoothed": un,
        "smoothed": sm,
        "pyamg_ua": base_un,
        "pyamg_sa": base,
        "ratios": ratio,
        # the solves that stopped short of the tolerance (MAXITER): their iteration ratios are null
        "max_iterations": MAXITER,
        "unconverged": [key for key, r in solves.items() if not r["converged"]],
    }


def _iterations_ratio(ours: dict, pyamg: dict) -> float | None:
    """Our iterations against pyamg's; None where either solve stopped short of the tolerance (a
    capped count is no count: a 1000:1 graded mesh, pyamg's 500 capped, gave "smoothed 0.38x")."""
    if not (ours["converged"] and pyamg["converged"]):
        return None
    return ours["iterations"] / max(pyamg["iterations"], 1)


def format_report(rep: dict) -> str:
    """A small table for the terminal."""
    lines = [
        f"{rep['problem']}; {rep['unknowns']} unknowns; our levels {' > '.join(map(str, rep['level_sizes']))}",
        f"{'solver':<29}{'iterations':>11}{'op. complexity':>16}{'setup [s]':>11}{'solve [s]':>11}",
    ]
    for name, key in (
        ("ours, unsmoothed", "unsmoothed"),
        ("pyamg std aggr., unsmoothed", "pyamg_ua"),
        ("ours, smoothed (Jacobi)", "smoothed"),
        ("pyamg std aggr., smoothed", "pyamg_sa"),
    ):
        r = rep[key]
        it = f"{r['iterations']}" + ("" if r["converged"] else "*")
        lines.append(
            f"{name:<29}{it:>11}{r['operator_complexity']:>16.3f}{r['setup_time']:>11.3f}{r['solve_time']:>11.3f}"
        )
    q = rep["ratios"]
    parts = []
    for kind, ours, theirs in (
        ("unsmoothed", "unsmoothed", "pyamg_ua"),
        ("smoothed", "smoothed", "pyamg_sa"),
    ):
        it, oc = q[f"{kind}_iterations_vs_pyamg"], q[f"{kind}_complexity_vs_pyamg"]
        if it is not None:
            parts.append(f"{kind} {it:.2f}x iterations at {oc:.2f}x complexity (pyamg {kind})")
            continue
        short = [k for k in (ours, theirs) if not rep[k]["converged"]]
        who = "pyamg's solve" if short == [theirs] else "our solve"
        why = "neither solve converged" if len(short) == 2 else f"{who} did not converge"
        parts.append(f"{kind}: no iteration ratio, {why}, {oc:.2f}x complexity (pyamg {kind})")
    lines.append("vs pyamg: " + "; ".join(parts))
    short = [rep[k] for k in ("unsmoothed", "pyamg_ua", "smoothed", "pyamg_sa") if not rep[k]["converged"]]
    if short:
        cap = rep.get("max_iterations", MAXITER)
        how = (
            f"hit the {cap}-iteration cap"
            if all(r["iterations"] >= cap for r in short)
            else f"stopped (at most {cap} iterations)"
        )
        lines.append(f"*: {how} without reaching the relative residual {TOL:.0e}".replace("e-0", "e-"))
    return "\n".join(lines)

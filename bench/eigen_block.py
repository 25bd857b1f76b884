"""Benchmark of issue 35 item 2: the eigen-solve's Krylov iteration and MUMPS's factorisation variants.

On the kappa = 25 cap (``examples/shell_kappa25.toml``'s O-grid at the sizes of ``bench/scale.py``), one
process per size, one thread:

* **Krylov iteration**: the ``k`` lowest elastic modes (the six rigid modes projected out, as the run does),
  shift-invert on one MUMPS LDL^T factorisation of ``K - sigma M`` (sigma the run's tiny negative shift), by
  ARPACK (single-vector solves, :func:`stepnf.linalg.eigen_extension.shift_invert_modes` below its block
  threshold) and by the block iteration (:mod:`stepnf.linalg.block_lanczos`, the run's path from
  ``BLOCK_MIN_DOFS`` dofs): seconds, shifted solves, the largest relative difference of the eigenvalues and
  the largest M-norm of a block mode outside ARPACK's eigenspace (its twin included; the last mode
  left out: it may be either twin of a pair cut by ``k``).
* **Factorisation variants** (``--blr``): MUMPS's block low-rank factorisation (ICNTL(35) = 2) at dropping
  thresholds CNTL(7), against the full-rank one: factorisation seconds, factor entries after compression (INFOG(35)), peak
  MUMPS memory (INFOG(22), MB), and the solve's backward error ``|A x - b| / |b|`` over 16 right-hand sides.
  (A single-precision factorisation is not offered: Debian's PETSc is built for double only.)

    .venv/bin/python bench/eigen_block.py --sizes 250k,1M [--blr] [--modes 31]

Writes ``bench/results/eigen_block.json`` (rows merged by size). Not a test: the numbers depend on the
machine and its load (recorded).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "bench" / "results" / "eigen_block.json"
SIZES = {"10k": (10, 4), "20k": (14, 7), "40k": (20, 10), "100k": (32, 16), "250k": (48, 24), "500k": (68, 34), "1M": (96, 48)}
BLR_DROPS = (1e-12, 1e-10, 1e-8)


def cap_matrices(n_core: int, n_ring: int):
    """K, M (CSR) of the cap at this O-grid, as the run reads them."""
    import tomllib

    from stepnf.pipeline.model import open_model
    from stepnf.plugin.adapter import checked_matrices
    from stepnf.scene.parse import parse_scene

    src = ROOT / "examples" / "shell_kappa25.toml"
    data = tomllib.loads(src.read_text())
    data["model"]["geometry"].update({"n_core": n_core, "n_ring": n_ring})
    adapter = open_model(parse_scene(data, file=src, base_dir=src.parent))
    try:
        K, M = checked_matrices(adapter)
    finally:
        adapter.close()
    return K.tocsr(), M.tocsr()


def child(size: str, k: int, blr: bool) -> dict:
    """One size in this process."""
    import resource

    import numpy as np

    import stepnf.linalg.eigen_extension as ee
    from stepnf.linalg.block_lanczos import BLOCK, block_shift_invert_modes
    from stepnf.linalg.factorization import factorize
    from stepnf.linalg.modal_analysis import lambda_scale

    K, M = cap_matrices(*SIZES[size])
    n = K.shape[0]
    sigma = -1e-10 * lambda_scale(K, M)
    t0 = time.perf_counter()
    fac = factorize((K - sigma * M).tocsr(), backend="mumps")
    t_fac = time.perf_counter() - t0
    ee.BLOCK_MIN_DOFS = 1 << 62  # ARPACK for the reference
    _, vr = ee.shift_invert_modes(K, M, sigma, fac, 6, None, [0])
    Q = vr @ np.linalg.inv(np.linalg.cholesky(vr.T @ (M @ vr))).T  # the rigid modes, M-orthonormal
    calls = [0]
    t0 = time.perf_counter()
    lam_a, vec_a = ee.shift_invert_modes(K, M, sigma, fac, k, Q, calls)
    row = {"size": size, "n_dofs": n, "modes": k, "factorization_seconds": round(t_fac, 2),
           "arpack": {"seconds": round(time.perf_counter() - t0, 2), "solves": calls[0]}}
    calls = [0]
    t0 = time.perf_counter()
    lam_b, vec_b = block_shift_invert_modes(M, sigma, lambda B: fac.solve(B, count=False), k, Q, calls,
                                            tol=ee.ARPACK_TOL, seed=ee.START_SEED)
    row["block"] = {"seconds": round(time.perf_counter() - t0, 2), "solves": calls[0], "block": BLOCK}
    row["max_rel_eigenvalue_difference"] = float(np.max(np.abs(lam_b - lam_a) / lam_a))
    # each block mode against ARPACK's eigenspace around it (twins within 1e-8 together); not the last
    # mode, which may be one twin of a pair cut by k (either twin is right)
    worst = 0.0
    for j in range(k - 1):
        near = np.flatnonzero(np.abs(lam_a - lam_a[j]) <= 1e-8 * lam_a[j])
        E = vec_b[:, j] - vec_a[:, near] @ (vec_a[:, near].T @ (M @ vec_b[:, j]))
        worst = max(worst, float(np.sqrt(E @ (M @ E))))
    row["max_mode_outside_arpack"] = worst
    fac.release()
    if blr:
        row["blr"] = blr_rows(K, M, sigma)
    row["peak_rss_mb"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
    return row


def blr_rows(K, M, sigma: float) -> list[dict]:
    """Full-rank and BLR factorisations of K - sigma M (module docstring)."""
    import numpy as np
    from petsc4py import PETSc

    from stepnf.errors import NumericalError
    from stepnf.linalg.factorization import factor_block_solve, mumps_ksp, mumps_setup, petsc_aij

    A = (K - sigma * M).tocsr()
    A.sort_indices()
    B = M @ np.random.default_rng(0).standard_normal((A.shape[0], 16))
    rows = []
    for drop in (None,) + BLR_DROPS:
        opts = PETSc.Options()
        for key in ("mat_mumps_icntl_35", "mat_mumps_cntl_7"):
            opts.delValue(key)
        if drop is not None:
            opts["mat_mumps_icntl_35"] = 2
            opts["mat_mumps_cntl_7"] = drop
        P = petsc_aij(A.indptr.astype(PETSc.IntType), A.indices.astype(PETSc.IntType), A.data, copy=True)
        ksp = mumps_ksp(P, symmetric=True)
        t0 = time.perf_counter()
        try:
            mumps_setup(ksp, "K - sigma M")
        except NumericalError as exc:  # e.g. INFOG(1) = -7, MUMPS's workspace beyond this machine
            rows.append({"cntl_7": drop, "error": str(exc)})
            ksp.destroy()
            P.destroy()
            continue
        t_fac = time.perf_counter() - t0
        F = ksp.getPC().getFactorMatrix()
        t0 = time.perf_counter()
        X = factor_block_solve(F, B)
        t_solve = time.perf_counter() - t0
        back = float(np.max(np.linalg.norm(A @ X - B, axis=0) / np.linalg.norm(B, axis=0)))
        rows.append({"cntl_7": drop, "factorization_seconds": round(t_fac, 2),
                     "solve_16_seconds": round(t_solve, 3), "factor_entries": int(F.getMumpsInfog(35)),
                     "mumps_peak_mb": int(F.getMumpsInfog(22)), "backward_error": back})
        ksp.destroy()
        P.destroy()
        PETSc.garbage_cleanup()  # MUMPS's factors otherwise stay in the process until the next collection
    for key in ("mat_mumps_icntl_35", "mat_mumps_cntl_7"):
        PETSc.Options().delValue(key)
    return rows


def main() -> None:
    if len(sys.argv) >= 2 and sys.argv[1] == "--child":
        print(json.dumps(child(sys.argv[2], int(sys.argv[3]), sys.argv[4] == "1")))
        return
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="250k", help=f"comma-separated, from {list(SIZES)}")
    ap.add_argument("--modes", type=int, default=31, help="elastic modes (the run's first batch from 200k dofs)")
    ap.add_argument("--blr", action="store_true", help="also the BLR factorisations")
    args = ap.parse_args()
    sizes = args.sizes.split(",")
    bad = [s for s in sizes if s not in SIZES]
    if bad:
        ap.error(f"--sizes {bad}: use {list(SIZES)}")
    doc = json.loads(OUT.read_text()) if OUT.exists() else {"rows": []}
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1",
               OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
    for size in sizes:
        load = os.getloadavg()
        p = subprocess.run([sys.executable, __file__, "--child", size, str(args.modes), str(int(args.blr))],
                           capture_output=True, text=True, env=env, cwd=ROOT)
        if p.returncode:
            raise SystemExit(f"{size} failed:\n{p.stderr[-3000:]}")
        row = json.loads(p.stdout.strip().splitlines()[-1])
        row["load_average_before"] = [round(x, 2) for x in load]
        row["date"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
        doc["rows"] = [r for r in doc["rows"] if r["size"] != size] + [row]
        a, b = row["arpack"], row["block"]
        print(f"{size:>5} {row['n_dofs']:>8} dofs, {args.modes} modes: ARPACK {a['seconds']:7.2f} s ({a['solves']} "
              f"solves), block of {b['block']} {b['seconds']:7.2f} s ({b['solves']} solves): "
              f"{a['seconds'] / b['seconds']:.2f}x; eigenvalues within {row['max_rel_eigenvalue_difference']:.1e}, "
              f"modes {row['max_mode_outside_arpack']:.1e}; factorisation {row['factorization_seconds']} s", flush=True)
        for r in row.get("blr", []):
            if "error" in r:
                print(f"      CNTL(7) {r['cntl_7'] or 'full rank':>9}: {r['error']}")
                continue
            print(f"      CNTL(7) {r['cntl_7'] or 'full rank':>9}: factorisation {r['factorization_seconds']:6.2f} s, "
                  f"{r['factor_entries']:>11} entries, MUMPS peak {r['mumps_peak_mb']} MB, 16 solves "
                  f"{r['solve_16_seconds']:.3f} s, backward error {r['backward_error']:.1e}")
        OUT.write_text(json.dumps(doc, indent=1) + "\n")  # after each size: a later failure keeps it
    print(f"written {OUT.relative_to(ROOT)}")


if __name__ == "__main__":
    main()

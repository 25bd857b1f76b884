"""Issue 33 item 5: the von Karman cap's backbones from the full Galerkin model's periodic orbits, beyond the
manifolds' validity limits.

The manifolds of docs/backbone/kappa25_manifolds.md stop being valid at W_max/h ~ 0.3-0.7 for (2,1), (0,2) and
(4,0), where the change of type of nonlinearity is decided or not. The von Karman model restricted to a master's
invariant subspace (:class:`stepnf.pipeline.modal_forces.VonKarmanForces`: the cos companions of ``k = j k_p``,
8 to 40 modes) is small enough to shoot: its brake orbits (:class:`stepnf.verify.periodic.Shooting`, DOP853 at
rtol 1e-12, the variational equations with the forces' analytic tangent) are continued in ``q0`` (the master's
modal coordinate at rest) from the linear mode, in steps of ``--step`` in W_max/h, each Newton started from the
secant through the two orbits before it, the step halved where Newton fails (down to 1/64 of it; then the
continuation stops there and says which modes are near a harmonic of the orbit). Those are orbits of the whole
model (the subspace is invariant), at every amplitude: no truncation of a series, no validity limit; what they
do not give is their stability against motions outside the subspace (the sin twins).

Per orbit: W_max/h (the largest ``|w| / h`` over 64 states a period on the polar grid of
:meth:`VonKarmanForces.transverse`), A (the master's amplitude), w_NL/w, the Newton iterations, the master's
share of the state at rest (``|x0_p| / |x0|``) and the modes within 1% of a harmonic ``k Omega`` (k <= 15). Per
mode: w_NL/w at the table's W_max/h (a cubic spline through the orbits), its extremum and where it crosses 1 (a
change of type). Writes ``bench/results/kappa25_vk_orbits.json`` (merged per model and mode).

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 nice .venv/bin/python bench/kappa25_vk_orbits.py \
        [--modes 21 02 40] [--top 1.5] [--step 0.025] [--model 16 16 28 40]

``--model``: the (k_max, n_transverse, n_galerkin, n_airy) of the von Karman model (default (8, 8, 20, 24); the
finer (16, 16, 28, 40) checks the truncation: 16 modes for (0,2), but 144 for (2,1), ~50 times the cost).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.optimize import brentq

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from stepnf.errors import NumericalError  # noqa: E402
from stepnf.models.vonkarman import VonKarmanShell  # noqa: E402
from stepnf.pipeline.modal_forces import VonKarmanForces  # noqa: E402
from stepnf.verify.periodic import Shooting  # noqa: E402

MODES = {"21": (2, 1), "02": (0, 2), "40": (4, 0)}
TARGETS = [0.1, 0.2, 0.3, 0.5, 0.7, 1.0, 1.2, 1.5]
OUT = ROOT / "bench" / "results" / "kappa25_vk_orbits.json"
SAMPLES = 64  # states a period for W_max/h
MAX_HALVINGS = 64  # the smallest step: step / 64


def orbits(model: VonKarmanShell, label: tuple[int, int], top: float, step: float) -> dict:
    """The brake orbits of ``label``'s cos mode from W_max/h ~ 0.02 to ``top`` (module docstring)."""
    p = model.index(*label)
    vf = VonKarmanForces(model, p)
    n = len(vf.index)
    j = int(np.flatnonzero(vf.index == vf.master)[0])
    omega = model.galerkin().omega[vf.index]
    w = float(omega[j])
    e = np.zeros(n)
    e[j] = 1.0
    sh = Shooting(np.eye(n), np.diag(omega ** 2), lambda x: vf(x)[0], e, w, tangent=vf.tangent, forces=vf,
                  integrator="explicit")
    lin = vf.transverse()
    peak = float(np.abs(lin(e[:, None])).max())

    def w_max(orb) -> float:
        S = sh.samples(orb.x0, orb.period, SAMPLES)[:, :n]
        return float(np.abs(lin(np.ascontiguousarray(S.T))).max())

    def near(Om: float) -> list[dict]:
        """Modes of the subspace within 1% of a harmonic k Omega (k <= 15) of the orbit: its internal resonances."""
        out = []
        for s_, ws in enumerate(omega):
            k = int(round(ws / Om))
            if s_ != j and 1 <= k <= 15 and abs(ws - k * Om) <= 0.01 * ws:
                out.append({"mode": int(vf.index[s_]), "harmonic": k, "gap": float(ws / (k * Om) - 1.0)})
        return out

    t0 = time.perf_counter()
    q0 = 0.02 / peak
    orb, prev, rows, failures, stopped = sh.orbit(q0, e * q0, 2 * np.pi / w), None, [], [], None
    while True:
        W = w_max(orb)
        rows.append({"W_over_h": W, "A": float(orb.amplitude), "q0": float(orb.q0), "w_ratio": float(orb.omega / w),
                     "newton_iterations": int(orb.newton_iterations), "residual": float(orb.residual),
                     "master_share": float(abs(orb.x0[j]) / np.linalg.norm(orb.x0)), "near": near(orb.omega)})
        print(f"{label} W/h {W:.4f} A {orb.amplitude:.6g} w/w {orb.omega / w:.7f} it {orb.newton_iterations} "
              f"share {rows[-1]['master_share']:.4f} {time.perf_counter() - t0:.0f} s", flush=True)
        if W >= top:
            break
        nxt, h = None, step
        while nxt is None:  # the step halved where Newton fails (a thin resonance tongue of the full model)
            q = orb.q0 * (W + h) / W
            if prev is None:
                guess = (orb.x0 * (q / orb.q0), orb.period)
            else:
                s = (q - orb.q0) / (orb.q0 - prev.q0)
                guess = (orb.x0 + s * (orb.x0 - prev.x0), orb.period + s * (orb.period - prev.period))
            try:
                nxt = sh.orbit(q, *guess)
            except NumericalError as exc:
                failures.append({"from_w_over_h": W, "step": h, "error": str(exc)})
                print(f"{label} step {h:.4g} from W/h {W:.4f} failed: {exc}", flush=True)
                h /= 2
                if h < step / MAX_HALVINGS:
                    stopped = {"at_w_over_h": W, "near": near(orb.omega), "error": str(exc)}
                    break
        if nxt is None:
            break
        prev, orb = orb, nxt
    Ws = np.asarray([r["W_over_h"] for r in rows])
    ratio = CubicSpline(Ws, [r["w_ratio"] for r in rows])
    at = {str(t): float(ratio(t)) for t in TARGETS if Ws[0] <= t <= Ws[-1]}
    fine = np.linspace(Ws[0], Ws[-1], 4001)
    vals = ratio(fine)
    d = vals - 1.0
    crossings = [float(brentq(lambda x: float(ratio(x)) - 1.0, fine[i], fine[i + 1]))
                 for i in np.flatnonzero(np.sign(d[1:]) * np.sign(d[:-1]) < 0)]
    i_ext = int(np.argmax(np.abs(d[: int(np.searchsorted(fine, crossings[0]))] if crossings else d)))
    return {"mode": int(p), "subspace_modes": int(n), "stiffness_ratio": float(sh.stiffness_ratio),
            "omega": w, "step_w_over_h": step, "orbits": rows, "w_ratio_at": at,
            "extremum_before_crossing": {"W_over_h": float(fine[i_ext]), "w_ratio": float(vals[i_ext])},
            "crosses_one_at_w_over_h": crossings, "failed_steps": failures, "stopped": stopped,
            "force_evaluations": int(sh.force_evaluations),
            "seconds": round(time.perf_counter() - t0, 1)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--modes", nargs="+", default=list(MODES), choices=sorted(MODES))
    ap.add_argument("--top", type=float, default=1.5, help="the last W_max/h (default 1.5)")
    ap.add_argument("--step", type=float, default=0.025, help="the step in W_max/h (default 0.025)")
    ap.add_argument("--model", nargs=4, type=int, default=[8, 8, 20, 24], metavar=("K_MAX", "N_T", "N_G", "N_AIRY"),
                    help="the von Karman model's (k_max, n_transverse, n_galerkin, n_airy) (default 8 8 20 24)")
    a = ap.parse_args()
    dims = tuple(a.model)
    model = VonKarmanShell(kappa=25.0, k_max=dims[0], n_transverse=dims[1], n_galerkin=dims[2], n_airy=dims[3])
    name = f"vonkarman kappa=25 nu=0.3 {dims}"
    for key in a.modes:
        res = orbits(model, MODES[key], a.top, a.step)
        doc = json.loads(OUT.read_text()) if OUT.exists() else {}  # read again: other runs may have written
        doc.setdefault(name, {})[str(MODES[key])] = res
        OUT.write_text(json.dumps(doc, indent=1) + "\n")
        print(f"{MODES[key]} ({name}): w_NL/w " + ", ".join(f"{k}: {v:.5f}" for k, v in res["w_ratio_at"].items())
              + f"; extremum {res['extremum_before_crossing']}; crosses 1 at W/h {res['crosses_one_at_w_over_h']}; "
              f"stopped {res['stopped']}; {res['seconds']} s", flush=True)


if __name__ == "__main__":
    main()

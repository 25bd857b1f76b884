"""Issue 33 item 5: the 1:1 twins of the kappa = 25 free-edge cap's asymmetric modes, von Karman model.

A scene cannot put a sin companion on a von Karman manifold (:mod:`stepnf.pipeline.modal_manifolds` works in
the cos-only invariant subspace of a master), so this script builds the larger invariant subspace that holds
both companions: the cos AND sin modes of ``k = j k_p`` (``k = 0``: cos only), with the Airy classes cos and sin
of ``kb = j k_p``. The forces are those of :class:`stepnf.pipeline.modal_forces.VonKarmanForces` with the sin
classes added (same potential; checked here: on cos-only fields they equal the cos subspace's forces, and they
commute with a rotation of the shell). The manifold is then parametrised and its branches traced exactly as the
pipeline does (:func:`~stepnf.dpim.multimode.manifold.parametrise_manifold`, probe 1, the pipeline's
``backbone_branches`` and ``manifold_report``), with W_max/h over the whole period of angles ``[0, 2 pi / k_p)``
(a travelling wave is not even in theta).

Default model (k_max, n_transverse, n_galerkin, n_airy) = (8, 8, 20, 24), kappa = 25, nu = 0.3.

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 nice .venv/bin/python bench/kappa25_twins_vk.py \
        [--case 21 40 21+41 21+41x2] [--orders 7 9]

Cases: ``21`` = [(2,1) cos, (2,1) sin] (modes 11, 12), ``40`` = [(4,0) cos, sin] (5, 6), ``21+41`` =
[(2,1) cos, sin, (4,1) cos] (11, 12, 22), ``21+41x2`` = [(2,1) cos, sin, (4,1) cos, sin] (11, 12, 22, 23).
For each: every branch the pipeline's tracer finds (kind from the phase of the twin's zeta: in-phase /
out-of-phase = standing waves turned, elliptic = travelling wave) at W_max/h = 0.1, 0.2, 0.3, 0.5, 0.7, 1.0
(w_NL/w, stability there, inside the validity limit or not), its validity limit and where its stability
changes; for the two-mode cases the standing wave computed with the twin at rest (:func:`standing`: the
tracer does not follow it on an exact O(2) pair, docs/backbone/kappa25_twins.md "A limitation") with the same
figures. Single-mode rows: docs/backbone/kappa25_manifolds.md. Writes ``bench/results/kappa25_twins_vk.json``
(merged per case and order).
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import scipy.sparse as sp

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from stepnf.dpim.manifold_report import _amplitude_at_w, _w_max_at, manifold_report  # noqa: E402
from stepnf.dpim.multimode.backbone import backbone_branches, omega_at, point_at  # noqa: E402
from stepnf.dpim.multimode.branches import ReducedSystem  # noqa: E402
from stepnf.dpim.multimode.manifold import parametrise_manifold  # noqa: E402
from stepnf.dpim.multimode.measures import OrbitMeasure  # noqa: E402
from stepnf.dpim.parametrisation import DPIM, DPIMTolerances, ModeSpectrum  # noqa: E402
from stepnf.models._couplings import trilinear  # noqa: E402
from stepnf.models._quadrature import angular_factors  # noqa: E402
from stepnf.models.vonkarman import VonKarmanShell  # noqa: E402
from stepnf.pipeline.modal_forces import RADII, VonKarmanForces  # noqa: E402

TARGETS = [0.1, 0.2, 0.3, 0.5, 0.7, 1.0]
CASES = {"21": [11, 12], "40": [5, 6], "21+41": [11, 12, 22], "21+41x2": [11, 12, 22, 23]}
OUT = ROOT / "bench" / "results" / "kappa25_twins_vk.json"
TOL = 1e-3          # validity tolerance (the scenes' default)
ANGLES_FULL = 97    # angles over [0, 2 pi / k_p) for W_max / h


class TwinForces:
    """Von Karman modal forces over the cos and sin modes of ``k = j k_p`` (module docstring)."""

    def __init__(self, model: VonKarmanShell, p: int):
        gd = self.data = model.galerkin()
        self.model = model
        kp = self.kp = int(gd.rows[p][1])
        assert kp > 0, "an axisymmetric mode has no twin"
        ks = [k for k in range(0, gd.k_max + 1, kp) if k in gd.families]
        self.modes = [("cos", k, i) for k in ks for i in range(len(gd.families[k].omega))]
        self.modes += [("sin", k, i) for k in ks if k > 0 for i in range(len(gd.families[k].omega))]
        self.index = np.asarray([gd.index[(k, i, c)] for c, k, i in self.modes])
        self.omega = gd.omega[self.index].copy()
        kbs = [k for k in range(0, 2 * max(ks) + 1, kp) if k in gd.airy_radial]
        self.classes = [("cos", kb) for kb in kbs] + [("sin", kb) for kb in kbs if kb > 0]
        m = len(self.modes)
        self.B, self.A, self.xi4 = [], [], []
        for cb, kb in self.classes:
            nb = gd.airy_radial[kb].shape[0]
            B = np.zeros((nb, m, m))
            for a, (ca, ka, ia) in enumerate(self.modes):
                for b, (cc, kc, ic) in enumerate(self.modes):
                    ang = angular_factors((cb, kb), (ca, ka), (cc, kc))
                    if ang == (0.0, 0.0):
                        continue
                    B[:, a, b] = trilinear(gd.airy_radial[kb], gd.families[ka].f, ka, gd.families[kc].f, kc,
                                           gd.r, gd.w, ang)[:, ia, ic]
            A = np.zeros((nb, m))
            for a, (ca, ka, ia) in enumerate(self.modes):
                if ka == kb and ca == cb:
                    A[:, a] = gd.families[kb].A[:, ia]
            self.B.append(0.5 * (B + B.transpose(0, 2, 1)))
            self.A.append(A)
            self.xi4.append(gd.xi4[kb])

    def __call__(self, X: np.ndarray) -> np.ndarray:
        X = np.atleast_2d(np.asarray(X, dtype=float))
        md = self.data
        root, eps = math.sqrt(md.kappa), md.eps_c
        out = X * self.omega ** 2
        for B, A, xi4 in zip(self.B, self.A, self.xi4):
            Bw = np.einsum("bij,kj->kbi", B, X, optimize=True)
            beta = np.einsum("kbi,ki->kb", Bw, X)
            a = X @ A.T
            out = out + eps * np.einsum("kb,kbi->ki", (0.5 * beta - root * a) / xi4, Bw)
            out = out - (0.5 * eps * root) * ((beta / xi4) @ A)
        return out

    def local(self, q: int) -> int:
        return int(np.flatnonzero(self.index == q)[0])

    def transverse(self):
        """``Y`` (m, j) -> ``w / h`` on a polar grid over ``[0, 2 pi / k_p)``."""
        r = np.linspace(0.0, 1.0, RADII)
        th = 2 * np.pi / self.kp * np.arange(ANGLES_FULL) / ANGLES_FULL
        R = np.asarray([self.model.radial_shape(int(s), r) for s in self.index])
        C = np.asarray([np.cos(k * th) if c == "cos" else np.sin(k * th) for c, k, _ in self.modes])
        Phi = (R[:, :, None] * C[:, None, :]).reshape(len(self.index), -1).T
        return lambda Y: Phi @ np.asarray(Y)

    def rotation(self, t0: float) -> np.ndarray:
        """The matrix of modal coordinates of the field turned by ``t0``."""
        m = len(self.modes)
        Rm = np.zeros((m, m))
        pos = {(c, k, i): a for a, (c, k, i) in enumerate(self.modes)}
        for a, (c, k, i) in enumerate(self.modes):
            if k == 0:
                Rm[a, a] = 1.0
                continue
            cs, sn = math.cos(k * t0), math.sin(k * t0)
            # cos k(th - t0) = cos k t0 cos + sin k t0 sin ; sin k(th - t0) = cos k t0 sin - sin k t0 cos
            if c == "cos":
                Rm[a, a] += cs
                Rm[pos[("sin", k, i)], a] += sn
            else:
                Rm[a, a] += cs
                Rm[pos[("cos", k, i)], a] -= sn
        return Rm


def checks(tf: TwinForces, model: VonKarmanShell, p: int) -> dict:
    """Consistency of the extended forces: cos-only fields against the cos subspace's, and rotation."""
    ref = VonKarmanForces(model, p)
    rng = np.random.default_rng(1)
    Xc = rng.standard_normal((3, len(ref.index))) * 0.3
    X = np.zeros((3, len(tf.index)))
    for a, q in enumerate(ref.index):
        X[:, tf.local(int(q))] = Xc[:, a]
    f = tf(X)
    fc = ref(Xc)
    cos_err = float(np.abs(f[:, [tf.local(int(q)) for q in ref.index]] - fc).max() / np.abs(fc).max())
    X2 = rng.standard_normal((3, len(tf.index))) * 0.3
    Rm = tf.rotation(0.37)
    rot_err = float(np.abs(tf(X2 @ Rm.T) - tf(X2) @ Rm.T).max() / np.abs(tf(X2)).max())
    return {"cos_only_vs_cos_subspace": cos_err, "rotation_equivariance": rot_err}


def kind_of(b, j: int, l: int) -> str:
    """A 1:1 coupled branch's kind from the phase of the twin's zeta relative to the master's."""
    if not b.kind.startswith("coupled"):
        return b.kind
    z = b.zeta[len(b.zeta) // 4]
    if abs(z[l]) < 1e-6 * abs(z[j]):
        return "coupled (twin at rest)"
    ph = np.angle(z[l] / z[j])
    if abs(math.sin(ph)) < 1e-6:
        return "in-phase (standing, turned)" if math.cos(ph) > 0 else "out-of-phase (standing, turned)"
    if abs(math.cos(ph)) < 1e-6:
        return f"elliptic (travelling wave, |z_twin/z| = {abs(z[l] / z[j]):.4f})"
    return f"mixed phase {ph:.4f} rad"


def standing(man, j: int, lin, order_cut: int | None = None) -> dict:
    """The standing wave of master ``j`` on ``man`` with every other master at rest (an invariant set of the
    reduced dynamics by symmetry: the cos subspace is invariant): ``Omega`` solves master j's equation, no
    continuation (the pipeline's tracer follows the rotated standing waves, a continuous family, instead).
    Returns functions of ``r = zeta_j`` (real): ``u(r)``, ``A(r)``, ``W(r)``; stability from the rotating
    frame's Jacobian (one zero eigenvalue: the rotation)."""
    system = ReducedSystem(man, np.ones(len(man.omega), dtype=int))
    measure = OrbitMeasure(man, system.k)
    m = system.m

    def u_of(r: float) -> np.ndarray:
        zeta = np.zeros(m, dtype=complex)
        zeta[j] = r
        F = system.field(zeta)
        u = np.concatenate([zeta.real, zeta.imag, [float((F[j] / (1j * r)).real), 0.0]])
        res = system.residual(u)
        assert np.abs(res).max() <= 1e-9 * abs(F[j]), ("standing wave not a solution", res)
        return u

    def A_of(r: float) -> float:
        return float(measure.amplitudes(u_of(r)[:m].astype(complex))[j])

    def W_of(r: float) -> float:
        return float(measure.w_max(u_of(r)[:m].astype(complex), lin, 1.0))
    return {"system": system, "measure": measure, "u": u_of, "A": A_of, "W": W_of}


def standing_report(man, j: int, lin, peak: float) -> dict:
    """The standing wave's w_NL/w at :data:`TARGETS`, stability along it, its validity against order N - 2."""
    from scipy.optimize import brentq
    from scipy.interpolate import CubicSpline
    N = int(man.order)
    hi = standing(man, j, lin)
    lo = standing(man.truncated(N - 2), j, lin)
    w = float(man.omega[j])
    rs = np.linspace(0.005, 1.2, 240) / peak / 2  # zeta ~ A / 2, W ~ peak A
    rows = []
    for r in rs:
        u = hi["u"](r)
        st, top = hi["system"].stability(u)
        J = hi["system"].jacobian(np.concatenate([u[:-1], [0.0]]))[:, :2 * hi["system"].m]
        ev = np.linalg.eigvals(J)
        rows.append({"r": r, "A": hi["A"](r), "W": hi["W"](r), "w_ratio": u[-2] / w, "stable": bool(st),
                     "max_re": top, "eig": ev})
        if rows[-1]["W"] > 1.25:
            break
    A = np.asarray([x["A"] for x in rows])
    AL = np.asarray([lo["A"](r) for r in rs[:len(rows)]])
    OL = np.asarray([lo["u"](r)[-2] for r in rs[:len(rows)]])
    grow = np.all(np.diff(AL) > 0)
    spl = CubicSpline(AL, OL) if grow else None
    valid = None
    for x in rows:
        df = abs(x["w_ratio"] * w - float(spl(x["A"]))) / (TOL * w) if spl is not None else np.inf
        zeta = np.zeros(hi["system"].m, dtype=complex)
        zeta[j] = x["r"]
        ds = hi["measure"].shape_difference(zeta, N - 2) / math.sqrt(TOL)
        x["excess"] = [df, ds]
        if valid is None and max(df, ds) > 1:
            valid = {"A": x["A"], "W": x["W"], "reason": "orders differ" if df >= ds else "shapes differ"}
    at = {}
    for t in TARGETS:
        try:
            r = brentq(lambda r: hi["W"](r) - t, rs[0], rows[-1]["r"], xtol=1e-14)
        except ValueError:
            at[str(t)] = "not reached"
            continue
        u = hi["u"](r)
        st, top = hi["system"].stability(u)
        at[str(t)] = {"A": hi["A"](r), "w_ratio": u[-2] / w, "stable": bool(st), "max_re": top,
                      "inside_validity": valid is None or hi["A"](r) <= valid["A"]}
    st = np.asarray([x["stable"] for x in rows])
    ch = np.flatnonzero(st[1:] != st[:-1])
    return {"kind": "standing wave (twin at rest)", "at": at, "valid": valid,
            "stable_at_start": bool(st[0]), "stability_changes_at_w_over_h": [rows[i + 1]["W"] for i in ch],
            "max_re_along": [[x["W"], x["max_re"], x["stable"]] for x in rows[::12]],
            "eig_first": [[float(e.real), float(e.imag)] for e in rows[0]["eig"]],
            "eig_at_w1": [[float(e.real), float(e.imag)] for e in min(rows, key=lambda x: abs(x["W"] - 1.0))["eig"]]}


def run_case(model: VonKarmanShell, case: str, order: int) -> dict:
    masters = CASES[case]
    tf = TwinForces(model, masters[0])
    chk = checks(tf, model, masters[0])
    n = len(tf.index)
    loc = [tf.local(q) for q in masters]
    dpim = DPIM(tf, sp.diags(tf.omega ** 2).tocsr(), sp.identity(n, format="csr"), ModeSpectrum(omega=tf.omega),
                tolerances=DPIMTolerances(resonance=0.05, twin=1e-6))
    t0 = time.perf_counter()
    man = parametrise_manifold(dpim, loc, np.eye(n)[:, loc], tf.omega[loc], order, probe=1.0)
    t_man = time.perf_counter() - t0
    lin = tf.transverse()
    peak = float(np.abs(lin(np.eye(n)[:, loc[0]])).max())
    fallback = 0.1 / peak
    spec = SimpleNamespace(order=order, amplitudes=None, w_over_h=TARGETS, tolerance=TOL, points=40,
                           resonance=None)
    j = 0
    top = 1.6 / peak  # trace to W_max/h ~ 1.6 of the linear mode
    t0 = time.perf_counter()
    branches = backbone_branches(man, j, top, r0=fallback / 200.0, tol=TOL, transverse=lin, h=1.0)
    branches.sort(key=lambda b: not b.kind.startswith("continues mode"))
    block = manifold_report(man, j, branches, spec, probe=1.0, resonance=0.05, transverse=lin, h=1.0)
    t_br = time.perf_counter() - t0
    w = float(man.omega[j])
    out = {"masters_model": masters, "masters_local": loc, "subspace_modes": int(n), "order": order,
           "checks": chk, "ratios": None if man.ratios is None else [int(x) for x in man.ratios],
           "flags": [str(f.get("message", f)) for f in man.flags], "time_manifold_s": round(t_man, 1),
           "time_branches_s": round(t_br, 1), "branches": []}
    for b in branches:
        measure = OrbitMeasure(man, b.ratios)
        system = ReducedSystem(man, b.ratios)
        row = {"kind": b.kind if b.kind.startswith("continues") else kind_of(b, j, 1),
               "valid_A": b.valid_A, "valid_reason": b.valid_reason,
               "valid_w_over_h": None, "W_range": [float(np.nanmin(b.W_max)), float(np.nanmax(b.W_max))],
               "stable_points": int(np.sum(b.stable)), "points": int(len(b.stable)), "at": {}}
        if b.valid_A:
            try:
                row["valid_w_over_h"] = _w_max_at(man, b, measure, float(b.valid_A), lin, 1.0)
            except Exception as exc:  # noqa: BLE001 - reported
                row["valid_w_over_h"] = f"failed: {exc}"
        # where stability changes along the branch (W_max/h at the first change)
        st = np.asarray(b.stable, dtype=bool)
        ch = np.flatnonzero(st[1:] != st[:-1])
        row["stability_changes_at_w_over_h"] = [float(b.W_max[i + 1]) for i in ch]
        row["stable_at_start"] = bool(st[0])
        for target in TARGETS:
            try:
                A = _amplitude_at_w(man, b, measure, target, lin, 1.0)
                u = point_at(man, b, A)
                Om = float(u[2 * system.m])
                stable, top_re = system.stability(u)
                zeta = u[:system.m] + 1j * u[system.m:2 * system.m]
                row["at"][str(target)] = {"A": A, "w_ratio": float(b.ratios[j]) * Om / w, "stable": bool(stable),
                                          "max_re": top_re, "A_all": [float(x) for x in measure.amplitudes(zeta)],
                                          "inside_validity": bool(b.valid_A is not None and A <= b.valid_A)}
            except Exception as exc:  # noqa: BLE001 - reported
                row["at"][str(target)] = f"not reached: {exc}"
        out["branches"].append(row)
    if len(masters) == 2:  # [mode, twin]: the standing wave with the twin at rest (with a 1:2 partner it is coupled)
        out["standing"] = standing_report(man, j, lin, peak)
    out["report_omega_ratio"] = block["omega_ratio"]
    out["report_flags"] = [str(f.get("message", f)) for f in block["flags"]]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", nargs="+", default=["21", "40"], choices=sorted(CASES))
    ap.add_argument("--orders", nargs="+", type=int, default=[7, 9])
    a = ap.parse_args()
    model = VonKarmanShell(kappa=25.0)
    doc = json.loads(OUT.read_text()) if OUT.exists() else {}
    doc["model"] = "vonkarman kappa=25 nu=0.3 (8, 8, 20, 24)"
    for case in a.case:
        for order in a.orders:
            t = time.perf_counter()
            res = run_case(model, case, order)
            res["time_total_s"] = round(time.perf_counter() - t, 1)
            doc.setdefault("cases", {})[f"{case}_o{order}"] = res
            OUT.write_text(json.dumps(doc, indent=1, default=float) + "\n")
            print(json.dumps({f"{case}_o{order}": res}, indent=1, default=float), flush=True)


if __name__ == "__main__":
    main()

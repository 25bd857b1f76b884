"""Benchmark of issue 35, item 5: stepnf side by side with SSMTool (run under GNU Octave) on one beam.

The beam is bench/polynomial_sparse.py's: SSMTool's ``examples/vonKarmanBeam`` (L = 1, h = 1e-3, b = 1,
E = 70e9, rho = 2700), clamped at both ends (34 elements: 99 dofs, 100: 297). Both tools get the SAME
tensors: ``beam_lists`` of that script, written as an ``.npz`` for stepnf and as 1-based coordinate lists
(``.mat``) that the Octave driver turns into SSMTool's ``sptensor``s (``fnl = {G, H}``, undamped).

SSMTool side (one fresh ``octave-cli`` process per case): ``DynamicalSystem`` (M, C = 0, K, fnl,
``notation = 'multiindex'``), ``linear_spectral_analysis``, a ``Manifold`` on the first mode pair,
``compute_whisker(order)`` (timed alone: "whisker s"), gamma from the order-(2j+1) reduced dynamics, then
the backbone Omega(rho) = omega0 + sum Im(gamma_j) rho^(2j) and, on each orbit of the parametrisation,
the amplitude of design.md ("Backbone amplitude": half the peak-to-peak of phi^T M x, phi mass-
normalised), the same as stepnf's. The ratio Omega / omega0 of the two is compared at stepnf's
amplitudes (SSMTool's curve through a cubic spline on 81 points).

SSMTool's source is used as checked out (``--ssmtool PATH``), never copied into this project; it needs
these to run under Octave 7 (Debian 12), all made at run time in a temporary folder:
- stand-ins on the path for MATLAB-only functions: ``matlab.mixin.SetGet``/``SetGetExactNames`` (base
  classes of DynamicalSystem, Manifold, the options), ``combvec`` (Deep Learning Toolbox, used in
  ``multi_nsumk``), ``lsqminnorm`` (cohomological_solution), ``eigs(..., 'smallestabs')``,
  ``sort(..., 'ComparisonMethod', 'real')`` and ``sortrows(A, cols, {'descend', 'ascend'})``
  (linear_spectral_analysis);
- a copy of ``src/`` with the edits of ``PATCHES`` (each fails loudly if it no longer applies): implicit
  expansion with a sparse operand (MATLAB only), Octave 7.3's ``nchoosek`` on a column vector and its
  ``intersect(..., 'rows', 'stable')`` third output (both wrong in 7.3);
- ``Manifold(DS)`` instead of ``SSM(DS)``: SSM has no constructor and Octave does not pass DS on to
  Manifold's (SSM adds only forced responses and plots).

    apt-get install -y --no-install-recommends octave
    OMP_NUM_THREADS=1 .venv/bin/python bench/peers_ssmtool.py --ssmtool /path/to/SSMTool \
        [--cases 99:3,99:5,99:7] [--commit SHA]

Writes ``bench/results/peers_ssmtool.json``. Not a test: the times depend on the machine and its load.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import scipy.io
from scipy.interpolate import CubicSpline

sys.path.insert(0, str(Path(__file__).resolve().parent))
from polynomial_sparse import BEAM, SCENE, beam_lists, timed_run  # noqa: E402  (the same beam, the same run)

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "bench" / "results" / "peers_ssmtool.json"

SHIMS = {
    "+matlab/+mixin/SetGet.m": """classdef SetGet < handle
  methods
    function set(obj, varargin)
      for k = 1:2:numel(varargin), obj.(varargin{k}) = varargin{k + 1}; end
    end
    function v = get(obj, name)
      v = obj.(name);
    end
  end
end
""",
    "+matlab/+mixin/SetGetExactNames.m": "classdef SetGetExactNames < matlab.mixin.SetGet\nend\n",
    "combvec.m": """function y = combvec(varargin)
  y = varargin{1};
  for k = 2:nargin
    b = varargin{k}; y = [repmat(y, 1, columns(b)); kron(b, ones(1, columns(y)))];
  end
end
""",
    "lsqminnorm.m": "function x = lsqminnorm(A, b)\n  x = pinv(full(A)) * full(b);\nend\n",
    "eigs.m": """function varargout = eigs(varargin)
  for k = 1:numel(varargin)
    if ischar(varargin{k}) && strcmpi(varargin{k}, 'smallestabs'), varargin{k} = 'sm'; end
  end
  varargout = cell(1, max(1, nargout)); [varargout{:}] = __eigs__(varargin{:});
end
""",
    "sort.m": """function varargout = sort(x, varargin)
  k = find(cellfun(@(a) ischar(a) && strcmpi(a, 'ComparisonMethod'), varargin), 1);
  varargout = cell(1, max(1, nargout));
  if isempty(k), [varargout{:}] = builtin('sort', x, varargin{:}); return; end
  real_only = strcmpi(varargin{k + 1}, 'real'); varargin(k:k + 1) = [];
  if ~real_only, [varargout{:}] = builtin('sort', x, varargin{:}); return; end
  [~, I] = builtin('sort', real(x), varargin{:}); varargout{1} = x(I);
  if nargout > 1, varargout{2} = I; end
end
""",
    "sortrows.m": """function [B, I] = sortrows(A, cols, dirs)
  if nargin < 2 || isempty(cols), cols = 1:columns(A); end
  if nargin == 3
    if ischar(dirs), dirs = repmat({dirs}, 1, numel(cols)); end
    cols = abs(cols) .* (1 - 2 * strcmpi(dirs, 'descend'));
  end
  I = (1:rows(A)).';
  for c = fliplr(cols(:).')
    if c < 0, d = 'descend'; else, d = 'ascend'; end
    [~, k] = sort(A(I, abs(c)), d); I = I(k);
  end
  B = A(I, :);
end
""",
}

# (file under src/, pattern, replacement, why): applied to a temporary copy of the checkout's src/
PATCHES = [
    ("@Manifold/private/multi_index_setup.m", r"Lambda_M_vector      = diag\(Lambda_M\);",
     "Lambda_M_vector      = full(diag(Lambda_M));", "sparse .* dense with implicit expansion"),
    ("@Manifold/private/coeffs_setup.m", r"Lambda_M_vector      = diag\(Lambda_M\);",
     "Lambda_M_vector      = full(diag(Lambda_M));", "sparse .* dense with implicit expansion"),
    ("@Manifold/cohomological_solution.m", r"L_k = L_k \+ Lambda_K\(f\)\*M\*Vm \+ Ym;",
     "L_k = full(L_k) + full(Lambda_K(f)*M*Vm + Ym);", "sparse + sparse with implicit expansion"),
    ("misc/nsumk.m", r"nchoosek\(\(1:\(k\+n-1\)\)',n-1\)", "nchoosek((1:(k+n-1)),n-1)",
     "Octave 7.3 nchoosek(column, 2) fails"),
] + [(f"@Manifold/private/{f}", r"\[~,~,(\w+)\] = intersect\(([^,]+),([^,]+),'rows','stable'\);",
      r"[~,\1] = ismember(\2,\3,'rows');", "Octave 7.3 intersect(...,'rows','stable') third output wrong")
     for f in ("coeffs_setup.m", "multi_index_setup.m", "multi_setup.m")]

DRIVER = r"""function peer_backbone(ssm, matfile, order)
here = pwd; run(fullfile(ssm, 'install.m')); cd(here);
d = load(matfile); n = double(d.n);
M = sparse(double(d.M_subs(:, 1)), double(d.M_subs(:, 2)), d.M_vals(:), n, n);
K = sparse(double(d.K_subs(:, 1)), double(d.K_subs(:, 2)), d.K_vals(:), n, n);
fnl = {sptensor(double(d.G_subs), d.G_vals(:), [n n n]), sptensor(double(d.H_subs), d.H_vals(:), [n n n n])};
DS = DynamicalSystem();
set(DS, 'M', M, 'C', sparse(n, n), 'K', K, 'fnl', fnl);
set(DS.Options, 'Emax', 5, 'Nmax', 10, 'notation', 'multiindex');
DS.linear_spectral_analysis();
S = Manifold(DS);
set(S.Options, 'reltol', 0.1, 'notation', 'multiindex');
S.choose_E([1 2]);
om0 = abs(imag(S.E.spectrum(1)));
[phi, ~] = eigs(K, M, 1, 'SM'); phi = phi / sqrt(phi.' * M * phi);
t1 = tic;
[W0, R0] = S.compute_whisker(order);
gamma = compute_gamma(R0);
printf('WHISKER_SECONDS %.4f\nOMEGA0 %.15g\n', toc(t1), om0);
rho_bb = sqrt(0.3 * om0 / abs(imag(gamma(1))));
th = linspace(0, 2 * pi, 257);
for rho = linspace(0, 1.3 * rho_bb, 82)(2:end)
  z = reduced_to_full_traj(th, rho * [exp(1i * th); exp(-1i * th)], W0);
  q = phi.' * M * z(1:n, :);
  om = om0 + sum(imag(gamma(:)) .* rho .^ (2 * (1:numel(gamma)).'));
  printf('BB %.17g %.17g %.17g\n', rho, (max(q) - min(q)) / 2, om / om0);
end
end
"""


def prepare(ssmtool: Path, work: Path) -> Path:
    """The shims and the patched copy of ``src/`` (``ext/`` and ``install.m`` linked); returns its root."""
    for rel, text in SHIMS.items():
        (work / "shim" / rel).parent.mkdir(parents=True, exist_ok=True)
        (work / "shim" / rel).write_text(text)
    root = work / "ssmtool"
    root.mkdir()
    shutil.copytree(ssmtool / "src", root / "src")
    for name in ("ext", "install.m"):
        (root / name).symlink_to(ssmtool / name)
    for rel, pat, rep, why in PATCHES:
        f = root / "src" / rel
        text, count = re.subn(pat, rep, f.read_text(errors="surrogateescape"))
        if not count:
            raise SystemExit(f"SSMTool patch no longer applies: src/{rel}: {why}")
        f.write_text(text, errors="surrogateescape")
    (work / "peer_backbone.m").write_text(DRIVER)
    return root


def run_ssmtool(root: Path, work: Path, n_dofs: int, order: int, lists: dict, octave: str) -> dict:
    """One fresh Octave process: wall s, peak RSS MB (wait4), whisker s, omega0 and the backbone (A, ratio)."""
    mat = work / f"beam{n_dofs}.mat"
    scipy.io.savemat(mat, {**{f"{k}_subs": lists[f"{k}_subs"] + 1 for k in "MKGH"},
                           **{f"{k}_vals": lists[f"{k}_vals"] for k in "MKGH"}, "n": float(lists["n"])})
    cmd = [octave, "--no-gui", "--norc", "--eval",
           f"addpath('{work / 'shim'}'); peer_backbone('{root}', '{mat}', {order})"]
    log, errlog = work / "octave.out", work / "octave.err"
    with log.open("w") as fo, errlog.open("w") as fe:
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, cwd=work, stdout=fo, stderr=fe)
        _, _, usage = os.wait4(proc.pid, 0)  # this process's own peak RSS
        wall = time.perf_counter() - t0
    out, err = log.read_text(), errlog.read_text()
    bb = np.array([[float(x) for x in ln.split()[1:]] for ln in out.splitlines() if ln.startswith("BB ")])
    vals = {ln.split()[0]: float(ln.split()[1]) for ln in out.splitlines()
            if ln.startswith(("WHISKER_SECONDS", "OMEGA0"))}
    if "WHISKER_SECONDS" not in vals or bb.size == 0:
        raise SystemExit(f"SSMTool failed at {n_dofs} dofs, order {order}:\n{err[-2000:]}")
    return {"wall": wall, "rss": usage.ru_maxrss / 1024, "whisker": vals["WHISKER_SECONDS"],
            "omega0": vals["OMEGA0"], "A": bb[:, 1], "ratio": bb[:, 2]}


def child(scene: str) -> dict:
    """stepnf's backbone (amplitudes and Omega / omega) of the scene, in this process."""
    from stepnf.pipeline.run import run_scene
    from stepnf.scene.parse import load_scene

    m = run_scene(load_scene(Path(scene)), write=False).modes[0]
    return {"omega": m.omega, "amplitude": m.backbone["amplitude"], "omega_ratio": m.backbone["omega_ratio"],
            "valid_up_to": m.backbone.get("valid_up_to")}


def run_stepnf(work: Path, n_dofs: int, order: int, lists: dict, env: dict) -> dict:
    """``stepnf run`` in a fresh process (wall s, peak RSS MB), then its backbone from a child process."""
    np.savez(work / f"beam{n_dofs}.npz", **lists)
    scene = work / f"beam{n_dofs}_o{order}.toml"
    scene.write_text(SCENE.format(file=f"beam{n_dofs}.npz", order=order))
    wall, rss, code = timed_run([str(ROOT / ".venv" / "bin" / "stepnf"), "run", str(scene), "-q"], env)
    if code:
        raise SystemExit(f"stepnf run failed ({code}) at {n_dofs} dofs, order {order}")
    out = subprocess.run([sys.executable, __file__, "--child", str(scene)], env=env, capture_output=True,
                         text=True, check=True)
    return {"wall": wall, "rss": rss, **json.loads(out.stdout.strip().splitlines()[-1])}


def compare(ssm: dict, nf: dict) -> list[dict]:
    """|Omega_SSMTool / Omega_stepnf - 1| at stepnf's amplitudes inside SSMTool's sampled range."""
    spline = CubicSpline(ssm["A"], ssm["ratio"])
    rows = []
    for A, r in zip(nf["amplitude"], nf["omega_ratio"]):
        if A is not None and r is not None and ssm["A"][0] <= A <= ssm["A"][-1]:
            s = float(spline(A)) * ssm["omega0"] / nf["omega"]
            rows.append({"amplitude": A, "ratio_stepnf": r, "ratio_ssmtool": s, "rel_diff": abs(s / r - 1)})
    return rows


def _nan(x: float | None) -> float:
    return float("nan") if x is None else x


def truncation(rows: list[dict], curves: dict) -> None:
    """Each case's truncation error, measured: SSMTool at this order against SSMTool at the highest order
    run for the same beam, at the same amplitudes as ``max_rel_diff_omega`` (the two tools agree to the
    truncation error when that difference is not larger than this)."""
    print(f"{'dofs':>5} {'order':>5} {'|stepnf - SSMTool|':>18} {'|SSMTool - SSMTool at top order|':>33}")
    for r in rows:
        top = max(o for n, o in curves if n == r["n_dofs"])
        ref, ssm = curves[(r["n_dofs"], top)], curves[(r["n_dofs"], r["order"])]
        amps = [c["amplitude"] for c in r["common_amplitudes"] if ref["A"][0] <= c["amplitude"] <= ref["A"][-1]]
        d = [abs(float(CubicSpline(ssm["A"], ssm["ratio"])(A) / CubicSpline(ref["A"], ref["ratio"])(A)) - 1)
             for A in amps]
        r["reference_order"], r["max_rel_diff_ssmtool_vs_reference"] = top, max(d, default=None)
        print(f"{r['n_dofs']:5d} {r['order']:5d} {_nan(r['max_rel_diff_omega']):18.2e} "
              f"{_nan(r['max_rel_diff_ssmtool_vs_reference']):33.2e}  (order {top})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ssmtool", help="SSMTool checkout (with install.m, src/, ext/)")
    ap.add_argument("--cases", default="99:3,99:5,99:7", help="N_DOFS:ORDER,...")
    ap.add_argument("--commit", help="SSMTool commit (default: git rev-parse in the checkout)")
    ap.add_argument("--octave", default="octave-cli")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        print(json.dumps(child(a.child), default=float))
        return
    if not a.ssmtool or not (Path(a.ssmtool) / "install.m").is_file() or not shutil.which(a.octave):
        ap.error("needs --ssmtool PATH (an SSMTool checkout with install.m) and octave-cli on PATH")
    ssmtool = Path(a.ssmtool).resolve()
    git = subprocess.run(["git", "-C", str(ssmtool), "rev-parse", "HEAD"], capture_output=True, text=True)
    commit = a.commit or (git.stdout.strip() if git.returncode == 0 else "unknown")
    version = subprocess.run([a.octave, "--version"], capture_output=True, text=True).stdout.splitlines()[0]
    env = {**os.environ, "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "1")}
    rows, curves = [], {}
    print(f"{'dofs':>5} {'order':>5} {'SSMTool s':>9} {'whisker s':>9} {'SSM MB':>7} {'stepnf s':>8} "
          f"{'nf MB':>6} {'ratio':>6} {'max dOmega':>10} {'at A_max':>9}")
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        root = prepare(ssmtool, work)
        for spec in a.cases.split(","):
            n_dofs, order = map(int, spec.split(":"))
            lists = beam_lists((n_dofs + 3) // 3)
            load = os.getloadavg()
            ssm = run_ssmtool(root, work, int(lists["n"]), order, lists, a.octave)
            ssm_mb = ssm["rss"]
            nf = run_stepnf(work, int(lists["n"]), order, lists, env)
            cmp = compare(ssm, nf)
            r = {"n_dofs": int(lists["n"]), "order": order, "load_avg_1_5_15": load,
                 "ssmtool_process_seconds": round(ssm["wall"], 2), "ssmtool_whisker_seconds": ssm["whisker"],
                 "ssmtool_peak_rss_mb": round(ssm_mb, 1), "stepnf_run_seconds": round(nf["wall"], 2),
                 "stepnf_run_peak_rss_mb": round(nf["rss"], 1),
                 "time_ratio_ssmtool_over_stepnf": round(ssm["wall"] / nf["wall"], 2),
                 "omega0_ssmtool": ssm["omega0"], "omega0_stepnf": nf["omega"],
                 "max_rel_diff_omega": max((c["rel_diff"] for c in cmp), default=None),
                 "valid_up_to_stepnf": nf["valid_up_to"], "common_amplitudes": cmp}
            rows.append(r)
            curves[(r["n_dofs"], order)] = ssm
            print(f"{r['n_dofs']:5d} {order:5d} {r['ssmtool_process_seconds']:9.2f} {ssm['whisker']:9.2f} "
                  f"{ssm_mb:7.1f} {r['stepnf_run_seconds']:8.2f} {r['stepnf_run_peak_rss_mb']:6.1f} "
                  f"{r['time_ratio_ssmtool_over_stepnf']:6.2f} {_nan(r['max_rel_diff_omega']):10.2e} "
                  f"{cmp[-1]['amplitude'] if cmp else float('nan'):9.3e}", flush=True)
    truncation(rows, curves)
    OUT.parent.mkdir(exist_ok=True)
    OUT.write_text(json.dumps({"beam": BEAM, "boundary": "clamped-clamped", "octave": version,
                               "ssmtool_commit": commit, "omp_num_threads": env["OMP_NUM_THREADS"],
                               "nproc": os.cpu_count(), "rows": rows}, indent=1, default=float) + "\n")
    print(f"wrote {OUT.relative_to(ROOT)}")


if __name__ == "__main__":
    main()

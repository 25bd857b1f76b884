"""stepnf and its FEniCSx adapters on Debian 13 (DOLFINx 0.9), in a chroot, against this Debian 12 run (issue 16).

A Debian 13 minbase tree with FEniCSx 0.9 (``python3-dolfinx-real``) and the
Debian packages stepnf uses is built once per machine and cached under the
ignored ``.cache/rootfs/`` (:func:`rootfs.derived_rootfs`). Each run copies
this checkout's files (``git ls-files``: no ``.venv``, results or caches, so
the chroot's ``.venv`` never meets the host's) into a temporary folder,
binds it into the tree (read-only otherwise) and, as a user would, runs
``bash scripts/setup.sh`` there; then

* the FEniCSx test files run inside (3D solid, shallow shell, materials,
  boundary conditions, form cache, ``mpirun -n 2`` with SLEPc and MUMPS);
  the CalculiX tests are skipped there (Debian 13 has no ``calculix-ccx``);
* ``examples/plate.toml`` (kappa = 0), ``examples/shell_kappa25.toml``
  (kappa = 25, the 38k-dof 3D model) and ``examples/shallow_shell_kappa25.toml``
  (kappa = 25, the shallow-shell model) run inside and with this
  interpreter (Debian 12, DOLFINx 0.5); frequencies, T and Gamma of every
  master mode and method must agree.

Needs root, debootstrap, unshare and chroot (else skipped) and the network
for the first build. The form cache of DOLFINx 0.9 is kept between runs in
``.cache/fenicsx-debian13``.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from helpers import rootfs
from helpers.paths import REPO

pytestmark = [pytest.mark.slow, pytest.mark.fenicsx]

ROOT = REPO
#: What the tree carries: FEniCSx 0.9 and everything scripts/setup.sh asks for but CalculiX (not in Debian 13),
#: a C compiler for the forms, and mpirun.
PACKAGES = ["python3-dolfinx-real", "python3-venv", "python3-setuptools", "python3-wheel", "python3-numpy",
            "python3-scipy", "python3-h5py", "python3-matplotlib", "python3-meshio", "python3-pytest",
            "python3-dask", "python3-distributed", "gcc", "libc6-dev", "python3-dev", "mpi-default-bin",
            "libopenblas0"]
FENICSX_TESTS = ["tests/solvers/fenicsx/test_fenicsx.py", "tests/solvers/fenicsx/test_fenicsx_boundary.py",
                 "tests/solvers/fenicsx/test_fenicsx_materials.py", "tests/solvers/fenicsx/test_fenicsx_cache.py",
                 "tests/models/test_shallow_shell.py", "tests/solvers/fenicsx/test_mpi.py"]
SCENES = ["plate", "shell_kappa25", "shallow_shell_kappa25"]
THREADS = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
#: Largest relative differences allowed between Debian 12 (DOLFINx 0.5.2, basix 0.5, PETSc 3.18, MUMPS 5.5,
#: SciPy 1.10, NumPy 1.24) and Debian 13 (DOLFINx 0.9.0, basix 0.9, PETSc 3.22, MUMPS 5.7, SciPy 1.15, NumPy 2.2),
#: about 5x what was measured (one thread each; in brackets). Same mesh, forms and algorithms: what differs is
#: round-off (the generated kernels, MUMPS's pivoting, ARPACK's iterations), amplified by the conditioning of
#: the eigen-problem. omega: [3.8e-10, plate and 3D cap; 1e-11 shallow shell] the shift-invert Lanczos of a
#: thin 3D solid, whose K spans bending to thickness modes. T and Gamma: [3.9e-9 plate, 9.9e-9 3D cap,
#: 6.4e-10 shallow shell] except the split twins (2,0) of the 3D cap [8.9e-8], whose mode shapes turn within
#: the pair under round-off alone (relative gap 1e-4, a mesh artefact; tests/solvers/fenicsx/test_mpi.py measured
#: 3e-8 between two eigen-solvers on one machine). So Gamma agrees to 1e-8 except for that pair, and for the exact twins
#: (2,0) of the shallow shell's disk [5.6e-9 since issue 14's eigen-solve (a 16-mode basis from a fixed ARPACK
#: start, where a 28-mode one from a random start measured 6.4e-10); that mode's own STEP error estimate of T
#: is 1.2e-9, so the difference is of the order of the result's round-off].
RTOL_OMEGA = 2e-9
RTOL_GAMMA = {"plate": 2e-8, "shell_kappa25": 5e-8, "shallow_shell_kappa25": 5e-9}
RTOL_GAMMA_TWINS = {("shell_kappa25", (2, 0)): 5e-7, ("shallow_shell_kappa25", (2, 0)): 3e-8}


class Debian13:
    """The tree and the copied checkout (``/opt/stepnf`` inside); :meth:`run` runs a command there."""

    def __init__(self, tree: Path, work: Path):
        self.tree, self.work = tree, work
        self.setup: subprocess.CompletedProcess | None = None  # what scripts/setup.sh did there
        self.jit = ROOT / ".cache" / "fenicsx-debian13"
        self.jit.mkdir(parents=True, exist_ok=True)

    def run(self, argv: list[str], timeout: float = 3600.0) -> subprocess.CompletedProcess:
        return rootfs.run_in_root(self.tree, argv, binds={str(self.work): "/opt", str(self.jit): "/mnt"},
                                  cwd="/opt/stepnf", read_only=True, timeout=timeout,
                                  env={**THREADS, "STEPNF_CACHE_DIR": "/mnt"})


@pytest.fixture(scope="module")
def debian13(tmp_path_factory) -> Debian13:
    rootfs.require("debootstrap")
    if not (ROOT / ".git").exists() or shutil.which("git") is None:
        pytest.skip("needs git and a git checkout (the files to copy)")
    tree = rootfs.derived_rootfs(rootfs.minbase_rootfs("trixie"), "trixie-fenicsx", PACKAGES)
    work = tmp_path_factory.mktemp("debian13")
    rootfs.copy_checkout(work / "stepnf")
    box = Debian13(tree, work)
    box.setup = box.run(["bash", "scripts/setup.sh"], timeout=900)
    assert box.setup.returncode == 0, box.setup.stdout[-3000:] + box.setup.stderr[-3000:]
    return box


def test_setup_installs_fenicsx_09_without_calculix(debian13):
    """scripts/setup.sh runs unchanged on Debian 13: FEniCSx 0.9, and a clear word about ccx."""
    assert "the calculix adapter needs the CalculiX program 'ccx'" in debian13.setup.stderr
    done = debian13.run([".venv/bin/python", "-c", "import dolfinx, stepnf_fenicsx; print(dolfinx.__version__)"])
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.strip().startswith("0.9"), done.stdout
    listed = debian13.run([".venv/bin/python", "-m", "stepnf", "solvers"])
    assert listed.returncode == 0 and "fenicsx" in listed.stdout, listed.stdout + listed.stderr


def test_the_fenicsx_tests_pass_on_debian13(debian13):
    done = debian13.run([".venv/bin/python", "-m", "pytest", "-q", "-p", "no:cacheprovider", "--basetemp=/tmp/pt",
                         "-m", "not calculix", *FENICSX_TESTS])
    summary = done.stdout[-3000:]
    print("Debian 13:", summary.strip().splitlines()[-1] if summary.strip() else "(no output)")
    assert done.returncode == 0, summary + done.stderr[-3000:]
    assert " passed" in summary and "failed" not in summary
    assert "no mpirun on PATH" not in summary  # the MPI path (SLEPc, MUMPS) really ran (mpi-default-bin)


def scene_results(done: subprocess.CompletedProcess) -> dict:
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout)


def compare(old: dict, new: dict) -> dict[tuple[int, ...], dict[str, float]]:
    """Per master mode: the relative differences of omega and the largest over the methods of T and Gamma."""
    assert [m["label"] for m in old["modes"]] == [m["label"] for m in new["modes"]]
    out = {}
    for a, b in zip(old["modes"], new["modes"]):
        row = {"omega": abs(a["omega"] - b["omega"]) / abs(a["omega"]), "T": 0.0, "gamma": 0.0}
        assert sorted(a["methods"]) == sorted(b["methods"])
        for name, ma in a["methods"].items():
            mb = b["methods"][name]
            assert [f["kind"] for f in ma["flags"]] == [f["kind"] for f in mb["flags"]], (a["label"], name)
            for key in ("T", "gamma"):
                x, y = ma.get(key), mb.get(key)
                if x is None or y is None:
                    assert x is y, (a["label"], name, key)
                    continue
                row[key] = max(row[key], abs(x - y) / max(abs(x), abs(y)))
        out[tuple(a["label"])] = row
    return out


@pytest.mark.parametrize("scene", SCENES)
def test_scene_on_debian13_matches_debian12(debian13, scene, tmp_path):
    pytest.importorskip("dolfinx")
    argv = ["-m", "stepnf", "run", f"examples/{scene}.toml", "--json", "--quiet", "--no-plot", "--no-hdf5"]
    new = scene_results(debian13.run([".venv/bin/python", *argv, "-o", f"/tmp/{scene}"]))
    old = scene_results(subprocess.run([sys.executable, *argv, "-o", str(tmp_path)], cwd=ROOT, capture_output=True,
                                       text=True, timeout=3600, env={**os.environ, **THREADS}))
    diffs = compare(old, new)
    for label, d in diffs.items():
        print(f"{scene} {label}: relative differences DOLFINx 0.5 vs 0.9: omega {d['omega']:.1e}, "
              f"T {d['T']:.1e}, Gamma {d['gamma']:.1e}")
    for label, d in diffs.items():
        tol = RTOL_GAMMA_TWINS.get((scene, label), RTOL_GAMMA[scene])
        assert d["omega"] <= RTOL_OMEGA, (label, d)
        assert d["T"] <= tol and d["gamma"] <= tol, (label, d, tol)

#!/usr/bin/env bash
# Set up everything stepnf needs on Debian 12 or 13, idempotently: Debian packages
# (FEniCSx, CalculiX where Debian has it, numpy/scipy/h5py built against them), then
# a virtual environment .venv that sees them (--system-site-packages) with stepnf and
# its solver adapters installed in editable mode, and Kratos Multiphysics 10.4.4 (pinned PyPI wheels,
# Python 3.11: Debian 12) for the kratos shell adapter. Fast when already done.
# Debian 12 gives FEniCSx 0.5 and CalculiX 2.20 (calculix-ccx: a set-up that cannot install it
# fails, naming it); Debian 13 gives FEniCSx 0.9 and no calculix-ccx package: there the
# calculix adapter needs a ccx program on PATH.
#   bash scripts/setup.sh          what the main job needs
#   bash scripts/setup.sh tests    and what the test suite drives besides: debootstrap and
#                                  podman (root file systems and container images built by the
#                                  slow image tests), python3-vtk9 (the VTK reader of ParaView,
#                                  which reads the field files back), mpirun (mpi-default-bin)
#                                  nbclient, ipykernel, nbformat, pandas (the notebook
#                                  docs/plate.ipynb, executed by tests/api/test_notebook.py)
#                                  (tests/required_tools.txt lists what the tests require)
# STEPNF_SETUP_DRY_RUN=1 prints the Debian packages it asks for and, after apt-get update, has
# apt-get simulate installing the missing ones (so an unknown package fails here too), then stops:
# nothing installed, no .venv.
#
# No pipelines here: under pipefail `cmd | grep -q ...` fails with 141 whenever grep exits at its
# first match and cmd dies of SIGPIPE writing the rest (issue 29: `apt-cache policy calculix-ccx |
# grep -q` dropped CalculiX 5 times in 6). Output is captured into a variable, then tested.
set -euo pipefail
case "${1:-}" in
  "") with_tests=0 ;;
  tests) with_tests=1 ;;
  *) echo "setup: unknown argument '$1' (allowed: nothing, or 'tests')" >&2; exit 2 ;;
esac
dry_run="${STEPNF_SETUP_DRY_RUN:-0}"
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"

apt_packages=(python3-venv python3-setuptools python3-wheel python3-numpy python3-scipy python3-h5py
  python3-matplotlib python3-meshio python3-pytest python3-dask python3-distributed
  python3-dolfinx-real libopenblas0)  # OpenBLAS, not the reference BLAS a minimal system falls back to
if [ "$with_tests" -eq 1 ]; then
  # python3-nbclient, python3-ipykernel, python3-nbformat: the suite executes docs/plate.ipynb;
  # python3-pandas: stepnf's optional DataFrame view (RunView.to_dataframe), used by that notebook
  # python3-gmsh: the tests write Gmsh meshes (.inp with facet elements, .msh) with Gmsh's own API
  apt_packages+=(debootstrap podman python3-vtk9 mpi-default-bin
    python3-nbclient python3-ipykernel python3-nbformat python3-pandas python3-gmsh)
fi
installed() {
  local status
  status="$(dpkg-query -W -f='${Status}' "$1" 2>/dev/null)" || return 1
  [ "$status" = "install ok installed" ]
}
# apt knows an installable calculix-ccx (asked again after apt-get update)
ccx_candidate() {
  local policy
  policy="$(apt-cache policy calculix-ccx 2>/dev/null)" || return 1
  [[ "$policy" == *"Candidate: "[0-9]* ]]
}
os_id=""; os_version=""
if [ -r /etc/os-release ]; then
  os_id="$(. /etc/os-release && echo "${ID:-}")"; os_version="$(. /etc/os-release && echo "${VERSION_ID:-}")"
fi
apt_lists() { compgen -G "/var/lib/apt/lists/*_Packages*" >/dev/null; }
# CalculiX: Debian 12 packages it (calculix-ccx 2.20) and this set-up promises it there: always asked
# for, whatever the package lists say before apt-get update (a fresh machine's may hold only the
# security updates) and whatever ccx is on PATH; one that cannot be installed is an error. Elsewhere
# (Debian 13 packages none) asked for where apt knows it, else the user's ccx on PATH is needed.
ccx_required=0; want_ccx=0
if [ "$os_id" = debian ] && [ "$os_version" = 12 ]; then
  ccx_required=1; want_ccx=1
elif ! command -v ccx >/dev/null 2>&1 && ! installed calculix-ccx; then
  if ! apt_lists || ccx_candidate; then want_ccx=1; fi
fi
if [ "$want_ccx" -eq 1 ]; then apt_packages+=(calculix-ccx); fi
missing=()
for p in "${apt_packages[@]}"; do installed "$p" || missing+=("$p"); done
if [ "$dry_run" = 1 ]; then echo "setup: Debian packages asked for: ${apt_packages[*]}"; fi
if [ ${#missing[@]} -gt 0 ]; then
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  $SUDO apt-get update -qq
  if [ "$want_ccx" -eq 1 ] && ! ccx_candidate; then  # known only now that the package lists are fresh
    if [ "$ccx_required" -eq 1 ]; then
      echo "setup: Debian 12 packages CalculiX as calculix-ccx, but apt-get finds no installable" \
        "calculix-ccx after apt-get update (is 'bookworm main' in /etc/apt/sources.list?): CalculiX" \
        "is not installed" >&2
      exit 1
    fi
    kept=(); for p in "${missing[@]}"; do [ "$p" = calculix-ccx ] || kept+=("$p"); done
    missing=("${kept[@]+"${kept[@]}"}")
  fi
  if [ ${#missing[@]} -gt 0 ]; then
    if [ "$dry_run" = 1 ]; then
      echo "setup: would install Debian packages: ${missing[*]}"
      simulated="$(apt-get install -s -y --no-install-recommends "${missing[@]}")" || {
        echo "setup: apt-get cannot install: ${missing[*]}" >&2; exit 1; }
      echo "setup: apt-get simulated it: $(grep -c '^Inst ' <<<"$simulated") packages with their dependencies"
    else
      echo "setup: installing Debian packages: ${missing[*]}"
      DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
    fi
  fi
fi
ccx_coming=0  # a dry run: calculix-ccx would be installed
if [ "$dry_run" = 1 ]; then for p in "${missing[@]+"${missing[@]}"}"; do [ "$p" != calculix-ccx ] || ccx_coming=1; done; fi
if [ "$ccx_coming" -eq 0 ] && ! command -v ccx >/dev/null 2>&1; then
  if [ "$ccx_required" -eq 1 ] && [ "$dry_run" != 1 ]; then
    echo "setup: calculix-ccx is installed but its program ccx is not on PATH ($PATH): CalculiX" \
      "cannot run (dpkg -L calculix-ccx shows where it is)" >&2
    exit 1
  fi
  if [ "$os_id" = debian ] && [ "$os_version" = 13 ]; then
    what="Debian 13 packages no CalculiX (no calculix-ccx package)"
  else
    what="this system (${os_id:-unknown} ${os_version:-}) has no calculix-ccx package apt can install"
  fi
  echo "setup: $what: stepnf and the FEniCSx adapters are set up without CalculiX; the calculix" \
    "adapter needs the CalculiX program 'ccx' on PATH (build it from source, or use Debian 12), and" \
    "its tests are skipped without it" >&2
fi
if [ "$dry_run" = 1 ]; then echo "setup: dry run (STEPNF_SETUP_DRY_RUN=1): nothing installed"; exit 0; fi

if [ ! -x .venv/bin/python ]; then
  echo "setup: creating .venv (with the system site packages, for FEniCSx)"
  /usr/bin/python3 -m venv --system-site-packages .venv
fi

# editable installs of the core and of every adapter distribution under solvers/
dists=(.)
for d in solvers/*/; do [ -f "$d/pyproject.toml" ] && dists+=("${d%/}"); done
stamp="$(sha256sum < <(cat pyproject.toml solvers/*/pyproject.toml 2>/dev/null))"; stamp="${stamp:0:16}"
if [ "$(cat .venv/.stepnf-stamp 2>/dev/null)" != "$stamp" ]; then
  echo "setup: installing stepnf and adapters: ${dists[*]}"
  args=()
  for d in "${dists[@]}"; do args+=(-e "$d"); done
  # --no-deps: numpy, scipy, h5py, dask... come from Debian, built against the same HDF5 and
  # MPI as FEniCSx (Debian names its h5py distribution differently, so pip would otherwise
  # fetch a second, incompatible h5py from PyPI)
  .venv/bin/python -m pip install -q --no-deps --no-build-isolation --disable-pip-version-check "${args[@]}"
  .venv/bin/python -m pip uninstall -y -q h5py 2>/dev/null || true  # a stray PyPI h5py from older set-ups
  echo "$stamp" > .venv/.stepnf-stamp
fi
# Kratos Multiphysics, the shells of the kratos adapter (solvers/kratos; BSD-4-Clause, a separate
# dependency, never vendored): pinned cp311 wheels from PyPI, --no-deps so that they import beside
# Debian's numpy and scipy (stepnf solves, so the LinearSolversApplication they list is not needed).
# Asked of pip only when the installed versions differ. Wheels exist for Python 3.11 only (Debian 12).
kratos_version=10.4.4
kratos_dists=(KratosMultiphysics KratosStructuralMechanicsApplication)
kratos_have="$(.venv/bin/python -c 'import sys
from importlib import metadata
for d in sys.argv[1:]:
    try:
        print(metadata.version(d))
    except metadata.PackageNotFoundError:
        print("none")' "${kratos_dists[@]}")"
kratos_want="$(printf '%s\n' "$kratos_version" "$kratos_version")"
py_tag="$(.venv/bin/python -c 'import sys; print(f"{sys.version_info[0]}.{sys.version_info[1]}")')"
if [ "$kratos_have" != "$kratos_want" ]; then
  if [ "$py_tag" = 3.11 ]; then
    echo "setup: installing Kratos Multiphysics $kratos_version (PyPI wheels) for the kratos adapter"
    .venv/bin/python -m pip install -q --no-deps --disable-pip-version-check \
      "${kratos_dists[@]/%/==$kratos_version}"
  else
    echo "setup: Kratos Multiphysics $kratos_version has wheels for Python 3.11 only, this venv runs $py_tag:" \
      "the kratos adapter is installed without its solver (its tests are skipped here)" >&2
  fi
fi
# FEniCSx form compilation cache inside the project
mkdir -p .cache

#!/usr/bin/env bash
# Set up everything stepnf needs on Debian 12 or 13, idempotently: Debian packages
# (FEniCSx, CalculiX where Debian has it, numpy/scipy/h5py built against them), then
# a virtual environment .venv that sees them (--system-site-packages) with stepnf and
# its solver adapters installed in editable mode. Fast when already done.
# Debian 12 gives FEniCSx 0.5 and CalculiX 2.20; Debian 13 gives FEniCSx 0.9 and no
# calculix-ccx package: there the calculix adapter needs a ccx program on PATH.
#   bash scripts/setup.sh          what the main job needs
#   bash scripts/setup.sh tests    and what the test suite drives besides: debootstrap and
#                                  podman (root file systems and container images built by the
#                                  slow image tests), python3-vtk9 (the VTK reader of ParaView,
#                                  which reads the field files back)
set -euo pipefail
case "${1:-}" in
  "") with_tests=0 ;;
  tests) with_tests=1 ;;
  *) echo "setup: unknown argument '$1' (allowed: nothing, or 'tests')" >&2; exit 2 ;;
esac
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"

apt_packages=(python3-venv python3-setuptools python3-wheel python3-numpy python3-scipy python3-h5py
  python3-matplotlib python3-meshio python3-pytest python3-dask python3-distributed
  python3-dolfinx-real libopenblas0)  # OpenBLAS, not the reference BLAS a minimal system falls back to
if [ "$with_tests" -eq 1 ]; then apt_packages+=(debootstrap podman python3-vtk9); fi
installed() { dpkg-query -W -f='${Status}' "$1" 2>/dev/null | grep -q "install ok installed"; }
# CalculiX: the calculix-ccx package where Debian has one (12), else a ccx of the user's (13 has none)
ccx_candidate() { apt-cache policy calculix-ccx 2>/dev/null | grep -q "Candidate: [0-9]"; }
# Debian 12 packages it: asked for there even when the package lists on the machine do not list it
# yet (a fresh machine's lists may hold only the security updates); dropped after apt-get update
# if it is still unknown
debian_12() { [ -r /etc/os-release ] && grep -q '^VERSION_ID="12"' /etc/os-release; }
apt_lists() { compgen -G "/var/lib/apt/lists/*_Packages*" >/dev/null; }
want_ccx=0
if ! command -v ccx >/dev/null 2>&1 && ! installed calculix-ccx; then
  if ! apt_lists || debian_12 || ccx_candidate; then want_ccx=1; apt_packages+=(calculix-ccx); fi
fi
missing=()
for p in "${apt_packages[@]}"; do installed "$p" || missing+=("$p"); done
if [ ${#missing[@]} -gt 0 ]; then
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  $SUDO apt-get update -qq
  if [ "$want_ccx" -eq 1 ] && ! ccx_candidate; then  # known only now that the package lists are there
    kept=(); for p in "${missing[@]}"; do [ "$p" = calculix-ccx ] || kept+=("$p"); done
    missing=("${kept[@]+"${kept[@]}"}")
  fi
  if [ ${#missing[@]} -gt 0 ]; then
    echo "setup: installing Debian packages: ${missing[*]}"
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
  fi
fi
if ! command -v ccx >/dev/null 2>&1; then
  echo "setup: this Debian has no calculix-ccx package (Debian 13 has none): stepnf and the FEniCSx" \
    "adapters are set up without CalculiX; the calculix adapter needs the CalculiX program 'ccx' on" \
    "PATH (build it from source, or use Debian 12), and its tests are skipped without it" >&2
fi

if [ ! -x .venv/bin/python ]; then
  echo "setup: creating .venv (with the system site packages, for FEniCSx)"
  /usr/bin/python3 -m venv --system-site-packages .venv
fi

# editable installs of the core and of every adapter distribution under solvers/
dists=(.)
for d in solvers/*/; do [ -f "$d/pyproject.toml" ] && dists+=("${d%/}"); done
stamp=$(cat pyproject.toml solvers/*/pyproject.toml 2>/dev/null | sha256sum | cut -c1-16)
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
# FEniCSx form compilation cache inside the project
mkdir -p .cache

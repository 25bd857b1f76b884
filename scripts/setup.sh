#!/usr/bin/env bash
# Set up everything stepnf needs on Debian 12, idempotently: Debian packages
# (FEniCSx, CalculiX, numpy/scipy/h5py built against them), then a virtual
# environment .venv that sees them (--system-site-packages) with stepnf and its
# solver adapters installed in editable mode. Fast when already done.
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
  python3-dolfinx-real calculix-ccx)
if [ "$with_tests" -eq 1 ]; then apt_packages+=(debootstrap podman python3-vtk9); fi
missing=()
for p in "${apt_packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "setup: installing Debian packages: ${missing[*]}"
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
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

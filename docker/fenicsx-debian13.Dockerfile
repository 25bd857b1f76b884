# stepnf with FEniCSx 0.9 (Debian 13 python3-dolfinx-real); Debian 13 packages no CalculiX, so the
# calculix adapter is installed but needs a ccx program (setup.sh says so). Installs through
# scripts/setup.sh, the script CI runs natively. Works read-only and as any user (the FEniCSx form
# cache then falls back to $XDG_CACHE_HOME or the temporary folder, with a note).
#   docker build -f docker/fenicsx-debian13.Dockerfile -t stepnf:fenicsx-debian13 .
#   docker run --rm -v "$PWD/examples:/scenes" stepnf:fenicsx-debian13 run /scenes/<scene>.toml
# BASE: any Debian 13 image; tests/env/test_images.py builds with podman from a local debootstrap
# import, --build-arg BASE=localhost/debian:13 (see docker/README.md).
ARG BASE=debian:13
FROM ${BASE}

ENV DEBIAN_FRONTEND=noninteractive \
    LANG=C.UTF-8 \
    OMP_NUM_THREADS=1

# FEniCSx in a layer of its own that does not depend on the sources (a rebuild after a source change
# reuses it); setup.sh installs every other package it needs and remains the authority on the list.
RUN apt-get update -qq \
 && apt-get install -y -qq --no-install-recommends ca-certificates python3 python3-dolfinx-real \
 && rm -rf /var/lib/apt/lists/*

WORKDIR /opt/stepnf
COPY . /opt/stepnf
RUN rm -rf .venv .cache \
 && bash scripts/setup.sh \
 && rm -rf /var/lib/apt/lists/* /root/.cache/pip \
 && .venv/bin/python -m compileall -q stepnf solvers
# fail the build early if FEniCSx 0.9 or the adapter is missing
RUN .venv/bin/python -c "import dolfinx, stepnf_fenicsx; assert dolfinx.__version__.startswith('0.9'), dolfinx.__version__; from stepnf.plugin.registry import installed_solvers; print(dolfinx.__version__, sorted(installed_solvers()))"

RUN mkdir -p /scenes
ENV PATH=/opt/stepnf/.venv/bin:$PATH
WORKDIR /scenes
ENTRYPOINT ["stepnf"]
CMD ["--help"]

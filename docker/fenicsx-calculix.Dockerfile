# stepnf with its bundled solvers: FEniCSx 0.5 (Debian 12 python3-dolfinx-real) and CalculiX ccx 2.20.
# Installs through scripts/setup.sh, the script CI runs natively. Works read-only and as any user
# (the FEniCSx form cache then falls back to $XDG_CACHE_HOME or the temporary folder, with a note).
#   docker build -f docker/fenicsx-calculix.Dockerfile -t stepnf:fenicsx-calculix .
#   docker run --rm -v "$PWD/examples:/scenes" stepnf:fenicsx-calculix run /scenes/<scene>.toml
# BASE: any Debian 12 image; tests/env/test_images.py builds with podman from a local debootstrap
# import, --build-arg BASE=localhost/debian:12 (see docker/README.md).
ARG BASE=debian:12
FROM ${BASE}

ENV DEBIAN_FRONTEND=noninteractive \
    LANG=C.UTF-8 \
    OMP_NUM_THREADS=1

# The two large Debian packages setup.sh installs, in a layer of their own that does not depend on the
# sources, so that a rebuild after a source change reuses it; setup.sh installs every other package
# it needs (as root here, so no sudo) and remains the authority on the list.
RUN apt-get update -qq \
 && apt-get install -y -qq --no-install-recommends ca-certificates python3 python3-dolfinx-real calculix-ccx \
 && rm -rf /var/lib/apt/lists/*

WORKDIR /opt/stepnf
COPY . /opt/stepnf
# setup.sh (after dropping a host's .venv and .cache, should a builder ignore the .dockerignore file),
# then byte-compile the sources (a read-only image cannot write __pycache__ at run time)
RUN rm -rf .venv .cache \
 && bash scripts/setup.sh \
 && rm -rf /var/lib/apt/lists/* /root/.cache/pip \
 && .venv/bin/python -m compileall -q stepnf solvers
# fail the build early if a solver is missing
RUN command -v ccx \
 && .venv/bin/python -c "import stepnf_calculix, stepnf_fenicsx; from stepnf.plugin.registry import installed_solvers; print(sorted(installed_solvers()))"

# the mount point of the scenes' folder, present also in a read-only container
RUN mkdir -p /scenes
ENV PATH=/opt/stepnf/.venv/bin:$PATH
WORKDIR /scenes
ENTRYPOINT ["stepnf"]
CMD ["--help"]

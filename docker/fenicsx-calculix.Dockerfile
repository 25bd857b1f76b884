# stepnf with its bundled solvers: FEniCSx 0.5 (Debian 12 python3-dolfinx-real) and CalculiX ccx 2.20.
# Installs through scripts/setup.sh, the script CI runs natively.
#   docker build -f docker/fenicsx-calculix.Dockerfile -t stepnf:fenicsx-calculix .
#   docker run --rm -v "$PWD/examples:/scenes" stepnf:fenicsx-calculix run /scenes/<scene>.toml
FROM debian:12

ENV DEBIAN_FRONTEND=noninteractive \
    LANG=C.UTF-8 \
    OMP_NUM_THREADS=1

# setup.sh installs every other Debian package it needs (as root here, so no sudo)
RUN apt-get update -qq \
 && apt-get install -y -qq --no-install-recommends ca-certificates python3 \
 && rm -rf /var/lib/apt/lists/*

WORKDIR /opt/stepnf
COPY . /opt/stepnf
RUN bash scripts/setup.sh \
 && rm -rf /var/lib/apt/lists/* /root/.cache/pip
# fail the build early if a solver is missing
RUN command -v ccx \
 && .venv/bin/python -c "import stepnf_calculix, stepnf_fenicsx; from stepnf.registry import installed_solvers; print(sorted(installed_solvers()))"

ENV PATH=/opt/stepnf/.venv/bin:$PATH
WORKDIR /scenes
ENTRYPOINT ["stepnf"]
CMD ["--help"]

# stepnf inside a code_aster image, so that the code_aster adapter finds run_aster on PATH.
# Installs stepnf through scripts/setup.sh, the script CI runs natively. The base image is a build
# argument (an official code_aster image built on Debian/Ubuntu, with run_aster on PATH):
#   docker build -f docker/code_aster.Dockerfile --build-arg ASTER_IMAGE=simvia/code_aster:latest \
#       -t stepnf:code_aster .
#   docker run --rm -v "$PWD/examples:/scenes" stepnf:code_aster run /scenes/<scene>.toml
ARG ASTER_IMAGE=simvia/code_aster:latest
FROM ${ASTER_IMAGE}

USER root
ENV DEBIAN_FRONTEND=noninteractive \
    LANG=C.UTF-8

WORKDIR /opt/stepnf
COPY . /opt/stepnf
# setup.sh installs the Debian packages it lists (apt-get) and the editable stepnf distributions
# (after dropping a host's .venv and .cache, should a builder ignore the .dockerignore file); the
# sources are byte-compiled, since a read-only container cannot write __pycache__ at run time
RUN rm -rf .venv .cache \
 && bash scripts/setup.sh \
 && rm -rf /var/lib/apt/lists/* /root/.cache/pip \
 && .venv/bin/python -m compileall -q stepnf solvers
# fail the build early if run_aster or the adapter is missing
RUN command -v run_aster \
 && .venv/bin/python -c "import stepnf_code_aster; from stepnf.plugin.registry import installed_solvers; print(sorted(installed_solvers()))"

# the mount point of the scenes' folder, present also in a read-only container
RUN mkdir -p /scenes
ENV PATH=/opt/stepnf/.venv/bin:$PATH
WORKDIR /scenes
ENTRYPOINT ["stepnf"]
CMD ["--help"]

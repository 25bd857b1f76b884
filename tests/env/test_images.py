"""The docker images, built and run without a registry (slow; needs root, podman and debootstrap).

For each entry of :data:`IMAGES`: the base suite's ``debootstrap --variant=minbase``
tree (:func:`rootfs.minbase_rootfs`, cached) is imported as a local base image
(again only when that tree was rebuilt), the Dockerfile is built with podman
from the repository root (the layer holding the sources and everything after
it is rebuilt from the current checkout; the Debian-package layer before it is
reused), and the image is mounted (``podman image mount``) and run with
``chroot`` (``podman run`` cannot set rlimits in this sandbox) the way
``docker run --read-only --user 65534:65534 -v SCENES:/scenes IMAGE ARGS`` runs
it: root file system read-only, the user ``nobody`` (home ``/nonexistent``),
the image's environment, working folder and entry point, no
``STEPNF_CACHE_DIR``. Each scene's numbers are compared with the same scene
run natively by this checkout.

Another image is one more :class:`Image` entry (Dockerfile, base suite, tag);
the measured times (debootstrap, import, build, each run) are printed at the
end of the module's run.
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from helpers.rootfs import COMPLETE, ROOT, TRUST_INSIDE, host_pip_cert, minbase_rootfs, require, run_in_root

pytestmark = pytest.mark.slow

NOBODY = "65534:65534"
LABEL = "org.stepnf.rootfs"  # on an imported base image: which cached tree it came from
SOURCES = ("stepnf", "solvers", "scripts", "templates", "tests")  # compared between checkout and image


@dataclass(frozen=True)
class Image:
    """A Dockerfile built on a local import of a debootstrap tree of ``suite`` tagged ``base``."""

    dockerfile: str  # relative to the repository root, with ARG BASE (its FROM) and a .dockerignore beside it
    suite: str
    base: str
    tag: str
    scenes: tuple[str, ...]  # entries of SCENES this image can run


#: scene (relative to a copy of the EXAMPLES folders) -> whether it compiles FEniCSx forms
SCENES = {"beam/beam_fenicsx.toml": True, "beam_ccx/beam_mesh.toml": False}
EXAMPLES = ("beam", "beam_ccx")  # beam_fenicsx.toml reads ../beam_ccx/beam_mesh.inp

IMAGES = [
    Image("docker/fenicsx-calculix.Dockerfile", "bookworm", "localhost/debian:12", "stepnf:fenicsx-calculix",
          tuple(SCENES)),
    # FEniCSx 0.9, no CalculiX (Debian 13 has no calculix-ccx): the FEniCSx beam against this Debian 12 run
    Image("docker/fenicsx-debian13.Dockerfile", "trixie", "localhost/debian:13", "stepnf:fenicsx-debian13",
          ("beam/beam_fenicsx.toml",)),
]


@dataclass
class Built:
    """A built image, mounted read-only at ``root``, with what ``docker run`` would take from it."""

    image: Image
    root: Path
    env: dict[str, str]
    entrypoint: list[str]
    workdir: str
    sources: dict[str, str]  # digests of the checkout's SOURCES just before the build
    times: dict[str, str] = field(default_factory=dict)


def podman(*args: str, timeout: float = 600.0, check: bool = True, **kw) -> subprocess.CompletedProcess:
    """``podman ARGS``, output captured; a failure fails the test with the end of podman's output."""
    r = subprocess.run(["podman", *args], capture_output=True, text=True, timeout=timeout, **kw)
    if check and r.returncode != 0:
        log = (r.stdout + r.stderr).splitlines()
        pytest.fail(f"podman {' '.join(args[:2])} failed (exit {r.returncode}):\n" + "\n".join(log[-40:]))
    return r


def pip_trust_volume() -> list[str]:
    """``podman build`` options that let pip in the build's RUN steps trust what the host's pip trusts
    (:func:`helpers.rootfs.host_pip_cert`): a pip.conf naming the host's bundle, both mounted read-only for
    the build only (a volume is not part of the image); none when the host's pip needs no bundle."""
    cert = host_pip_cert()
    if cert is None:
        return []
    conf = ROOT / ".cache" / "pip-trust.conf"
    conf.parent.mkdir(parents=True, exist_ok=True)
    conf.write_text(f"[global]\ncert = {TRUST_INSIDE}\n")
    return ["--volume", f"{cert}:{TRUST_INSIDE}:ro", "--volume", f"{conf}:/etc/pip.conf:ro"]


def image_id(ref: str) -> str | None:
    r = podman("image", "inspect", "--format", "{{.Id}}", ref, check=False)
    return r.stdout.strip() if r.returncode == 0 else None


def import_base(tree: Path, image: Image) -> bool:
    """Import ``tree`` as ``image.base`` unless that image already came from this very tree; True if imported."""
    mark = (tree / COMPLETE).stat()
    key = f"{image.suite}-{mark.st_ino}-{mark.st_mtime_ns}"  # a rebuilt tree has a new marker file
    r = podman("image", "inspect", "--format", "{{index .Labels \"" + LABEL + "\"}}", image.base, check=False)
    if r.returncode == 0 and r.stdout.strip() == key:
        return False
    old = image_id(image.base)
    tar = subprocess.Popen(["tar", "-C", str(tree), f"--exclude=./{COMPLETE}", "-c", "."], stdout=subprocess.PIPE)
    try:
        podman("import", "--change", f"LABEL {LABEL}={key}", "-", image.base, stdin=tar.stdout)
    finally:
        tar.stdout.close()
        assert tar.wait() == 0, f"tar -C {tree} failed"
    if old and old != image_id(image.base):
        podman("rmi", old, check=False)  # refused while images built on it exist: harmless
    return True


def digests(top: Path) -> dict[str, str]:
    """sha256 of every file under ``top``'s SOURCES folders, by relative path (no byte-code, no egg-info)."""
    out = {}
    for name in SOURCES:
        for path in sorted((top / name).rglob("*")):
            rel = path.relative_to(top)
            if path.is_file() and not {"__pycache__", ".pytest_cache"} & set(rel.parts) \
                    and not any(p.endswith(".egg-info") for p in rel.parts):
                out[str(rel)] = hashlib.sha256(path.read_bytes()).hexdigest()
    return out


def config(ref: str) -> dict:
    return json.loads(podman("image", "inspect", "--format", "{{json .Config}}", ref).stdout)


def home_of(root: Path, uid: str) -> str:
    """The home folder of ``uid`` in the image's /etc/passwd (docker run sets HOME from it)."""
    for line in (root / "etc" / "passwd").read_text().splitlines():
        fields = line.split(":")
        if len(fields) > 5 and fields[2] == uid:
            return fields[5]
    return "/"


@pytest.fixture(scope="module", params=IMAGES, ids=lambda im: im.tag)
def built(request) -> Iterator[Built]:
    require("podman", "debootstrap", "tar")
    image: Image = request.param
    times: dict[str, str] = {}
    t0 = time.monotonic()
    tree = minbase_rootfs(image.suite)
    t1 = time.monotonic()
    imported = import_base(tree, image)
    t2 = time.monotonic()
    times["debootstrap"] = f"{t1 - t0:.1f} s" + ("" if t1 - t0 > 5 else " (cached tree)")
    times["import"] = f"{t2 - t1:.1f} s" + ("" if imported else " (base image reused)")
    sources = digests(ROOT)
    old = image_id(image.tag)
    dockerfile = ROOT / image.dockerfile
    podman("build", "--isolation=chroot", "--network=host", "--pull=never",  # the base is the local import
           "--build-arg", f"BASE={image.base}", "--ignorefile", f"{dockerfile}.dockerignore",
           *pip_trust_volume(), "-f", str(dockerfile), "-t", image.tag, ".", cwd=ROOT, timeout=3600)
    times["build"] = f"{time.monotonic() - t2:.1f} s"
    if old and old != image_id(image.tag):
        podman("rmi", old, check=False)  # the previous build's image (its Debian-package layer stays in use)
    cfg = config(image.tag)
    root = Path(podman("image", "mount", image.tag).stdout.strip())
    try:
        env = dict(item.split("=", 1) for item in cfg.get("Env") or [])
        env["HOME"] = home_of(root, NOBODY.split(":")[0])
        yield Built(image, root, env, list(cfg.get("Entrypoint") or []), cfg.get("WorkingDir") or "/", sources,
                    times)
    finally:
        podman("image", "unmount", image.tag, check=False)
        report_times(request.config, f"{image.tag} times: " + ", ".join(f"{k} {v}" for k, v in times.items()))


def report_times(config, line: str) -> None:
    """Print ``line`` on the terminal, past pytest's output capture."""
    reporter = config.pluginmanager.get_plugin("terminalreporter")
    capture = config.pluginmanager.get_plugin("capturemanager")
    if reporter is not None and capture is not None:
        with capture.global_and_fixture_disabled():
            reporter.write_line("\n" + line)


def run(built: Built, args: list[str], scenes: Path | None = None) -> subprocess.CompletedProcess:
    """The image's entry point with ``args``, read-only, as nobody, ``scenes`` bound at the working folder."""
    binds = {str(scenes): built.workdir} if scenes else {}
    return run_in_root(built.root, [*built.entrypoint, *args], binds=binds, env=built.env, user=NOBODY,
                       cwd=built.workdir if scenes else "/", read_only=True, timeout=900)


def test_version_read_only_and_not_root(built):
    r = run(built, ["--version"])
    assert r.returncode == 0, r.stderr
    from importlib.metadata import version
    assert r.stdout.strip() == f"stepnf {version('stepnf')}"
    assert "STEPNF_CACHE_DIR" not in built.env and "XDG_CACHE_HOME" not in built.env
    # the premise of the runs below: nothing of the image can be written, and the user is not root
    probe = run_in_root(built.root, ["sh", "-c", "id -u; touch /opt/stepnf/probe"], env=built.env,
                        user=NOBODY, read_only=True, timeout=60)
    assert probe.returncode != 0 and probe.stdout.strip() == "65534", probe.stdout + probe.stderr
    assert not (built.root / "opt" / "stepnf" / "probe").exists()


def test_image_holds_this_checkout(built):
    """The sources in the image are the checkout's (a rebuild really rebuilt them), local state left out."""
    now = digests(ROOT)
    inside = digests(built.root / "opt" / "stepnf")
    # files created, changed or removed in the checkout while the image was built are left out
    steady = {k for k in set(now) | set(built.sources) if now.get(k) == built.sources.get(k)}
    stale = sorted(k for k in steady if inside.get(k) != now.get(k))
    assert not stale, f"image sources differ from the checkout: {stale[:10]}"
    opt = built.root / "opt" / "stepnf"
    assert not (opt / ".git").exists() and not (opt / ".cache" / "rootfs").exists()
    # the image's own .venv (editable installs of /opt/stepnf), not the checkout's
    urls = [p.read_text() for p in (opt / ".venv").rglob("direct_url.json")]
    assert urls and all("file:///opt/stepnf" in u for u in urls), urls


def scenes_copy(dest: Path, owner: str | None = None) -> Path:
    for name in EXAMPLES:
        shutil.copytree(ROOT / "examples" / name, dest / name, ignore=shutil.ignore_patterns("results"))
    if owner:
        uid, gid = (int(x) for x in owner.split(":"))
        for path in [dest, *dest.rglob("*")]:
            os.chown(path, uid, gid)
    return dest


@pytest.mark.parametrize("scene", list(SCENES))
def test_scene_runs_read_only_as_nobody(built, scene, tmp_path):
    if scene not in built.image.scenes:
        pytest.skip(f"{built.image.tag} does not run {scene}")
    native_dir = scenes_copy(tmp_path / "native")
    t0 = time.monotonic()
    native = subprocess.run([sys.executable, "-m", "stepnf", "run", scene, "--json"], cwd=native_dir,
                            capture_output=True, text=True, timeout=900,
                            env={**os.environ, "OMP_NUM_THREADS": "1"})
    t1 = time.monotonic()
    assert native.returncode == 0, native.stderr
    inside = run(built, ["run", scene, "--json"], scenes_copy(tmp_path / "image", owner=NOBODY))
    built.times[f"run {scene}"] = f"native {t1 - t0:.1f} s, image {time.monotonic() - t1:.1f} s"
    assert inside.returncode == 0, inside.stderr
    assert "Traceback" not in inside.stderr

    # the terminal shows progress lines and, for FEniCSx only, one note: no traceback, no chatter
    lines = inside.stderr.splitlines()
    notes = [line for line in lines if line.startswith("stepnf: warning:")]
    assert all(line.startswith("[stepnf] ") or line in notes for line in lines), inside.stderr
    if SCENES[scene]:  # nobody's home is /nonexistent and /opt is read-only: the cache goes to /tmp
        assert len(notes) == 1 and "form cache" in notes[0] and "/tmp/stepnf-65534/fenicsx" in notes[0], lines
    else:
        assert not notes, lines

    ours, theirs = json.loads(inside.stdout), json.loads(native.stdout)
    assert ours["model"]["n_dofs"] == theirs["model"]["n_dofs"]
    assert ours["hdf5"].startswith(built.workdir + "/")
    for mine, ref in zip(ours["modes"], theirs["modes"], strict=True):
        # Same sources inside and out, but not the same round-off: another BLAS or thread count (the
        # reference BLAS against OpenBLAS moved omega by 4e-10 for FEniCSx and 5e-9 for CalculiX here)
        # and, in the Debian 13 image, DOLFINx 0.9, PETSc 3.22 and MUMPS 5.7 (3.8e-10 on the caps of
        # tests/env/test_debian13.py), amplified by the conditioning of a slender beam (L/h = 100):
        # 5e-8 leaves a factor 10.
        assert mine["omega"] == pytest.approx(ref["omega"], rel=5e-8)
        for method, value in ref["methods"].items():
            # T comes from STEP's differences f(q) + f(-q) ~ 2 q^2 G, which cancel most digits of
            # the forces: the perturbed mode shape moves T by what the run's own STEP error estimate
            # T_error bounds. Measured: CalculiX (forces printed with 7 digits) T_error 4e-5, image
            # against native 9e-7 (1 against 2 OpenBLAS threads natively: 2.5e-6); FEniCSx T_error
            # 2e-8, image against native 3.5e-9.
            tol = max(value["T_error"], mine["methods"][method]["T_error"])
            assert mine["methods"][method]["T"] == pytest.approx(value["T"], rel=tol), method

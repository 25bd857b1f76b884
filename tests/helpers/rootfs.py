"""Debian root file systems for the slow tests that try stepnf on another system.

``minbase_rootfs("bookworm")`` runs ``debootstrap --variant=minbase`` once per
machine and keeps the result under the project's ignored ``.cache/rootfs/``
folder (built in a temporary sibling folder and renamed when complete, so an
interrupted build is never mistaken for a finished one); the image test turns
it into a container base image, the Debian 13 test installs FEniCSx 0.9 in it.
``run_in_root`` runs a command inside such a tree (or a mounted container
image) in a private mount namespace, with ``/proc``, ``/dev`` (with a private
``/dev/shm``), a read-only ``/sys``, a fresh ``/tmp`` and the given folders
bound in, optionally as another user: what ``podman run`` or ``docker run``
would give, where they cannot run.

Both need root, ``debootstrap``, ``unshare`` and ``chroot``; :func:`require`
skips the calling test where not root, fails it where a tool the set-up installs is missing.
"""
from __future__ import annotations

import fcntl
import os
import shlex
import shutil
import subprocess
from pathlib import Path

import pytest

from helpers import required
from helpers.paths import REPO

ROOT = REPO
CACHE = ROOT / ".cache" / "rootfs"
MIRROR = "http://deb.debian.org/debian"
COMPLETE = ".stepnf-rootfs-complete"


def require(*tools: str) -> None:
    """Skip the calling test unless running as root; fail it where ``tools`` (and unshare, chroot) are missing.

    A tool of ``tests/required_tools.txt`` that the set-up installs on this release fails the test when
    missing (:func:`required.need`); other missing tools skip it.
    """
    if os.geteuid() != 0:
        pytest.skip("needs root (debootstrap, mounts and chroot)")
    missing = [t for t in ("unshare", "chroot", *tools) if shutil.which(t) is None]
    if missing:  # a failure for a tool the set-up installs on this Debian release (debootstrap, podman)
        required.need(*missing)


def host_pip_cert() -> Path | None:
    """The certificate bundle the host's pip trusts when it is not pip's own (``PIP_CERT``, else ``cert`` in
    ``/etc/pip.conf``), None when pip uses its own. A machine whose network reaches PyPI through a proxy
    that re-signs TLS (this project's machines) has one; a fresh tree or a container build on it shares the
    host's network, so it needs that bundle too, as it needs the host's resolver: without it, pip's
    downloads there fail with CERTIFICATE_VERIFY_FAILED (scripts/setup.sh installs Kratos's wheels
    from PyPI)."""
    cert = os.environ.get("PIP_CERT")
    if not cert and Path("/etc/pip.conf").is_file():
        for line in Path("/etc/pip.conf").read_text().splitlines():
            key, _, value = line.partition("=")
            if key.strip() == "cert" and value.strip():
                cert = value.strip()
    return Path(cert) if cert and Path(cert).is_file() else None


#: where :func:`host_pip_trust` puts the host's bundle inside a tree or build (not a path Debian manages)
TRUST_INSIDE = "/etc/stepnf-host-ca.crt"


def host_pip_trust(tree: Path) -> dict[str, str]:
    """Copy the host's pip certificate bundle (:func:`host_pip_cert`) into ``tree`` at :data:`TRUST_INSIDE`
    and return the environment that has pip inside use it (``{}`` when the host's pip needs none)."""
    cert = host_pip_cert()
    if cert is None:
        return {}
    shutil.copy(cert, tree / TRUST_INSIDE.lstrip("/"))
    return {"PIP_CERT": TRUST_INSIDE}


def minbase_rootfs(suite: str, *, timeout: float = 1200.0) -> Path:
    """A ``debootstrap --variant=minbase SUITE`` tree, built once and cached under ``.cache/rootfs/``."""
    CACHE.mkdir(parents=True, exist_ok=True)
    dest = CACHE / suite
    with open(CACHE / f"{suite}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # one build at a time, others wait and reuse it
        if (dest / COMPLETE).exists():
            return dest
        work = CACHE / f"{suite}.partial"
        shutil.rmtree(work, ignore_errors=True)
        shutil.rmtree(dest, ignore_errors=True)
        subprocess.run(["debootstrap", "--variant=minbase", suite, str(work), MIRROR],
                       check=True, capture_output=True, text=True, timeout=timeout)
        (work / COMPLETE).write_text(suite + "\n")
        work.rename(dest)
    return dest


def run_in_root(root: Path, argv: list[str], *, binds: dict[str, str] | None = None,
                env: dict[str, str] | None = None, user: str | None = None, cwd: str = "/",
                read_only: bool = False, timeout: float = 1800.0) -> subprocess.CompletedProcess:
    """Run ``argv`` chrooted in ``root``, in a private mount namespace.

    ``binds`` maps host folders to absolute paths inside ``root`` (created if
    missing, unless ``read_only``); ``user`` is ``"UID:GID"`` for
    ``chroot --userspec``; ``read_only`` remounts the root itself read-only
    (so only the binds, ``/dev`` and the fresh ``/tmp`` are writable); ``env`` replaces
    the environment (PATH and HOME have defaults). Output is captured as text.
    """
    binds = dict(binds or {})
    script = ["set -e", "mount --make-rprivate /"]
    if read_only:  # a read-only bind of the tree on itself; writable mounts go on top
        script += [f"mount --bind {shlex.quote(str(root))} {shlex.quote(str(root))}",
                   f"mount -o remount,bind,ro {shlex.quote(str(root))}"]
    q = {name: shlex.quote(str(root / name)) for name in ("proc", "dev", "dev/shm", "sys", "tmp")}
    script += [f"mount -t proc proc {q['proc']}",
               f"mount --rbind /dev {q['dev']}",
               f"if [ -d {q['dev/shm']} ]; then mount -t tmpfs -o mode=1777 tmpfs {q['dev/shm']}; fi",  # private
               f"mount -t tmpfs -o mode=1777 tmpfs {q['tmp']}"]
    if (root / "sys").is_dir():  # read-only, as in a container (hwloc, under MPI, reads the CPU topology)
        script += [f"mount --rbind /sys {q['sys']}", f"mount -o remount,bind,ro {q['sys']}"]
    for host, inside in binds.items():
        target = root / inside.lstrip("/")
        if not read_only:
            target.mkdir(parents=True, exist_ok=True)
        script.append(f"mount --bind {shlex.quote(host)} {shlex.quote(str(target))}")
    spec = f"--userspec={user} " if user else ""
    inner = f"cd {shlex.quote(cwd)} && exec {shlex.join(argv)}"
    script.append(f"exec chroot {spec}{shlex.quote(str(root))} /bin/sh -c {shlex.quote(inner)}")
    base_env = {"PATH": "/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin",
                "HOME": "/tmp", "LANG": "C.UTF-8"}
    base_env.update(env or {})
    return subprocess.run(["unshare", "--mount", "--fork", "/bin/sh", "-c", "\n".join(script)],
                          env=base_env, capture_output=True, text=True, timeout=timeout)


def derived_rootfs(base: Path, name: str, packages: list[str], *, timeout: float = 1800.0) -> Path:
    """``base`` plus the Debian ``packages``, built once and cached as ``.cache/rootfs/NAME``.

    The base tree is copied (``cp -a``, never changed in place), the packages
    are installed with ``apt-get`` chrooted in the copy, and the copy is renamed
    into place when complete. The completion mark records the package list: a
    different list rebuilds the tree rather than reusing a tree without them.
    """
    CACHE.mkdir(parents=True, exist_ok=True)
    dest = CACHE / name
    mark = " ".join(sorted(packages)) + "\n"
    with open(CACHE / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if (dest / COMPLETE).exists() and (dest / COMPLETE).read_text() == mark:
            return dest
        work = CACHE / f"{name}.partial"
        shutil.rmtree(work, ignore_errors=True)
        shutil.rmtree(dest, ignore_errors=True)
        subprocess.run(["cp", "-a", str(base), str(work)], check=True, timeout=timeout)
        (work / COMPLETE).unlink(missing_ok=True)
        if Path("/etc/resolv.conf").exists():  # the chroot shares the host's network, not its resolver
            shutil.copy("/etc/resolv.conf", work / "etc" / "resolv.conf")
        install = ("apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "
                   "--no-install-recommends " + shlex.join(packages) + " && apt-get clean")
        done = run_in_root(work, ["/bin/sh", "-c", install], timeout=timeout)
        if done.returncode != 0:
            raise RuntimeError(f"installing {packages} in {work} failed:\n{done.stdout[-3000:]}\n"
                               f"{done.stderr[-3000:]}")
        (work / COMPLETE).write_text(mark)
        work.rename(dest)
    return dest


def copy_checkout(dest: Path) -> None:
    """This checkout's tracked and new, not ignored, files (the work tree, as ``git ls-files`` lists it).

    Symbolic links are copied as links (the adapters' ``templates`` folders are links into ``templates/``).
    """
    names = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"], cwd=ROOT,
                           capture_output=True, check=True).stdout.decode().split("\0")
    for name in filter(None, names):
        src = ROOT / name
        if src.is_symlink():
            (dest / name).parent.mkdir(parents=True, exist_ok=True)
            os.symlink(os.readlink(src), dest / name)
        elif src.is_file():
            (dest / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / name)

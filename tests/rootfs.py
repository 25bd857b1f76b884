"""Debian root file systems for the slow tests that try stepnf on another system.

``minbase_rootfs("bookworm")`` runs ``debootstrap --variant=minbase`` once per
machine and keeps the result under the project's ignored ``.cache/rootfs/``
folder (built in a temporary sibling folder and renamed when complete, so an
interrupted build is never mistaken for a finished one); the image test turns
it into a container base image, the Debian 13 test installs FEniCSx 0.9 in it.
``run_in_root`` runs a command inside such a tree (or a mounted container
image) in a private mount namespace, with ``/proc``, ``/dev``, a fresh
``/tmp`` and the given folders bound in, optionally as another user.

Both need root, ``debootstrap``, ``unshare`` and ``chroot``; :func:`require`
skips the calling test where any is missing.
"""
from __future__ import annotations

import fcntl
import os
import shlex
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
CACHE = ROOT / ".cache" / "rootfs"
MIRROR = "http://deb.debian.org/debian"
COMPLETE = ".stepnf-rootfs-complete"


def require(*tools: str) -> None:
    """Skip the calling test unless running as root with ``tools`` (and unshare, chroot) on PATH."""
    if os.geteuid() != 0:
        pytest.skip("needs root (debootstrap, mounts and chroot)")
    missing = [t for t in ("unshare", "chroot", *tools) if shutil.which(t) is None]
    if missing:
        pytest.skip(f"needs {', '.join(missing)} (bash scripts/setup.sh tests installs them)")


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
    (so only the binds and the fresh ``/tmp`` are writable); ``env`` replaces
    the environment (PATH and HOME have defaults). Output is captured as text.
    """
    binds = dict(binds or {})
    script = ["set -e", "mount --make-rprivate /"]
    if read_only:  # a read-only bind of the tree on itself; writable mounts go on top
        script += [f"mount --bind {shlex.quote(str(root))} {shlex.quote(str(root))}",
                   f"mount -o remount,bind,ro {shlex.quote(str(root))}"]
    script += [f"mount -t proc proc {shlex.quote(str(root / 'proc'))}",
               f"mount --rbind /dev {shlex.quote(str(root / 'dev'))}",
               f"mount -t tmpfs -o mode=1777 tmpfs {shlex.quote(str(root / 'tmp'))}"]
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

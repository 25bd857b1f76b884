"""Write a file atomically: every file stepnf produces goes through here.

One job: a file is either the complete new version or the untouched previous
one, never a half-written mix, whatever happens (full disk, crash, two runs
writing the same file). How:

1. The content is built **in memory** first. HDF5 files are made by h5py on
   an :class:`io.BytesIO` (:func:`hdf5_bytes`), so the HDF5 library never
   writes to the disk itself (on a full disk it used to crash inside h5py
   with a segmentation fault while closing the file).
2. The bytes are written with plain Python I/O to a temporary file
   ``.<name>.<random>.tmp`` in the target folder (same file system, so the
   rename below is atomic; created ``O_EXCL | O_NOFOLLOW``), then ``fsync``-ed.
3. ``os.replace`` puts it in place; the folder is ``fsync``-ed (best effort).

Links: stepnf never writes through a symbolic link (a received folder may hold
``NAME.h5 -> ../victim``). A link where the file goes is refused with an
:class:`OutputError` naming it, its target untouched; steps 2 and 3 work relative
to one open descriptor of the folder, and ``rename`` replaces a link planted
after that check rather than following it. A folder stepnf makes for itself
(the checkpoint folder, ``private_folder``) must not be a link either; the
user's output folder may (a results folder on another disk is their choice).
:func:`linked` finds such links before a run starts.

Private folders: a folder whose content a later run trusts (the checkpoint
folder: forces reused; FEniCSx's form cache: compiled code loaded) must be the
user's alone. :func:`make_private` creates it 0700 whatever the umask;
:func:`unsafe_reason` says why an existing one is not (another user's, or
group- or world-writable); :func:`private_folder` does both for a cache.

Any failure removes the temporary file and raises :class:`OutputError`
naming the file and the reason ("no space left on device", ...); the
previous file, if any, is untouched.

Permissions: a new file gets ``0666 & ~umask``, like any file the user
creates (``tempfile.mkstemp`` would give 0600). A file that already exists
keeps its permission bits (``rwx`` for user, group, others; not its owner,
nor setuid/setgid bits) when it is replaced, as editors and ``sed -i`` do:
a store made group-writable stays so.

Versions: every stepnf HDF5 file carries root attributes ``format`` (what it
is, e.g. ``"stepnf-run"``) and ``format_version`` (an integer, raised when
the layout changes incompatibly). :func:`check_format` is the readers' side:
it refuses a foreign file and a newer version with a :class:`StoreError`.
"""
from __future__ import annotations

import errno as _errno
import io
import os
import secrets
import stat
from pathlib import Path
from typing import Any, Callable, Iterable

from stepnf.errors import OutputError, StoreError

__all__ = ["write_bytes", "hdf5_bytes", "write_hdf5", "check_format", "check_folder", "reason", "linked",
           "make_private", "unsafe_reason", "private_folder"]


def reason(exc: BaseException) -> str:
    """What went wrong, in words: ``"no space left on device (ENOSPC)"``."""
    if isinstance(exc, OSError) and exc.errno is not None:
        text = exc.strerror or os.strerror(exc.errno)
        name = _errno.errorcode.get(exc.errno)
        text = text[:1].lower() + text[1:]
        return f"{text} ({name})" if name else text
    return str(exc) or type(exc).__name__


def _link_error(path: Path, what: str) -> OutputError:
    try:
        target = f" (to {os.readlink(path)})"
    except OSError:
        target = ""
    return OutputError(f"cannot write the {what} {path}: {path} is a symbolic link{target}; stepnf never writes "
                       "through a link: remove it or choose another output folder", path=path)


def _open_folder(folder: Path, *, private: bool, mkdir: bool) -> int:
    """A file descriptor of ``folder`` (created if ``mkdir``); with ``private`` it must be no symbolic link
    and is created 0700 (:func:`make_private`; its parent as any folder of the user's)."""
    if mkdir and not private:
        folder.mkdir(parents=True, exist_ok=True)
    elif mkdir:
        folder.parent.mkdir(parents=True, exist_ok=True)
        make_private(folder)
    flags = os.O_RDONLY | getattr(os, "O_DIRECTORY", 0) | getattr(os, "O_CLOEXEC", 0)
    return os.open(folder, flags | (getattr(os, "O_NOFOLLOW", 0) if private else 0))


def make_private(path: Path) -> None:
    """Create ``path`` and its missing parents with mode 0700 (chmod-ed: the umask may be 000); a folder
    already there is left as it is (:func:`unsafe_reason` judges it), one that cannot be made is left to
    the writer or :func:`check_folder` to explain."""
    missing = []
    p = Path(path)
    while not os.path.lexists(p) and p != p.parent:
        missing.append(p)
        p = p.parent
    for p in reversed(missing):
        try:
            os.mkdir(p, 0o700)
            os.chmod(p, 0o700)
        except FileExistsError:
            continue
        except OSError:
            return


def _unsafe_stat(st: os.stat_result, p: Path, owners: tuple[int, ...], sticky_ok: bool) -> str | None:
    """Why the folder ``p`` of status ``st`` is not private: not one of ``owners``', or writable by group
    or others (unless sticky, like /tmp, when ``sticky_ok``)."""
    if st.st_uid not in owners:
        return f"{p} belongs to another user (uid {st.st_uid})"
    if st.st_mode & 0o022 and not (sticky_ok and st.st_mode & stat.S_ISVTX):
        return f"{p} is writable by others (mode {stat.S_IMODE(st.st_mode):04o})"
    return None


def unsafe_reason(path: Path, *, parent: bool = True) -> str | None:
    """Why ``path`` is no folder to trust the content of (compiled code to load, stored forces to reuse),
    or ``None``: it must be this user's and not group- or world-writable; with ``parent``, its parent too
    must not be writable by others (unless sticky like /tmp) and be this user's or root's (else another
    user could swap the folder for theirs)."""
    if not hasattr(os, "geteuid"):
        return None
    uid = os.geteuid()
    checks = [(Path(path), (uid,), False)] + ([(Path(path).parent, (uid, 0), True)] if parent else [])
    for p, owners, sticky_ok in checks:
        try:
            st = os.stat(p)
        except OSError as exc:
            return f"{p} cannot be examined ({exc.strerror or exc})"
        why = _unsafe_stat(st, p, owners, sticky_ok)
        if why:
            return why
    return None


def private_folder(path: Path) -> tuple[str | None, str | None]:
    """Make ``path`` a private folder (:func:`make_private`): ``(why no file can be written there, why it is
    not safe)`` (:func:`check_folder`, :func:`unsafe_reason`), each ``None`` when all is well."""
    make_private(path)
    why = check_folder(path)
    return why, (None if why else unsafe_reason(path))


def write_bytes(path: str | Path, data: bytes | bytearray | memoryview, *, what: str = "file",
                mkdir: bool = True, private_folder: bool = False) -> Path:
    """Write ``data`` to ``path`` atomically (see the module docstring); return the path.

    ``what`` names the file in error messages ("results file", "sweep store").
    Raises :class:`OutputError` (with ``path`` and ``errno``) on any failure.

    Never through a symbolic link: a link at ``path`` is refused (an :class:`OutputError` naming
    it; its target is untouched), and with ``private_folder`` (a folder stepnf makes for itself,
    the checkpoint folder) so is a link in place of the folder, or a folder of another user or
    writable by others; a missing one is created 0700 (:func:`make_private`). The temporary file is created
    with ``O_EXCL | O_NOFOLLOW`` and renamed relative to one descriptor of the folder, so a link
    planted after the check is replaced by the file (``rename`` never follows its destination),
    never written through. The user's output folder itself may be a link.
    """
    path = Path(path)
    folder = path.parent
    name = path.name
    tmp = f".{name}.{secrets.token_hex(4)}.tmp"
    fd = dfd = -1
    try:
        try:
            dfd = _open_folder(folder, private=private_folder, mkdir=mkdir)
        except OSError as exc:
            if private_folder and os.path.islink(folder):
                raise _link_error(folder, what) from exc
            raise
        why = _unsafe_stat(os.fstat(dfd), folder, (os.geteuid(),), False) \
            if private_folder and hasattr(os, "geteuid") else None
        if why:  # another user's folder, or one others can write into: never trusted, never written
            raise OutputError(f"cannot write the {what} {path}: {why}; stepnf keeps this folder private: "
                              "remove it", path=path)
        try:
            st = os.stat(name, dir_fd=dfd, follow_symlinks=False)
        except FileNotFoundError:
            st = None
        if st is not None and stat.S_ISLNK(st.st_mode):
            raise _link_error(path, what)
        keep_mode = stat.S_IMODE(st.st_mode) & 0o777 if st is not None and stat.S_ISREG(st.st_mode) else None
        # O_EXCL | O_NOFOLLOW: never write through someone else's file or link; 0o666: the umask applies
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0)
                     | getattr(os, "O_CLOEXEC", 0), 0o666, dir_fd=dfd)
        if keep_mode is not None:
            os.fchmod(fd, keep_mode)
        view = memoryview(data).cast("B")
        while view:
            n = os.write(fd, view)
            view = view[n:]
        os.fsync(fd)
        os.close(fd)
        fd = -1
        os.replace(tmp, name, src_dir_fd=dfd, dst_dir_fd=dfd)
        try:
            os.fsync(dfd)
        except OSError:  # some file systems cannot fsync a folder; the rename is done anyway
            pass
    except BaseException as exc:
        if fd >= 0:
            try:
                os.close(fd)
            except OSError:
                pass
        if dfd >= 0:
            try:
                os.unlink(tmp, dir_fd=dfd)
            except OSError:
                pass
        if isinstance(exc, OSError):
            raise OutputError(f"cannot write the {what} {path}: {reason(exc)}", path=path,
                              errno=exc.errno) from exc
        raise
    finally:
        if dfd >= 0:
            os.close(dfd)
    return path


def write_text(path: str | Path, text: str, *, what: str = "file") -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically, like :func:`write_bytes`."""
    return write_bytes(path, text.encode("utf-8"), what=what)


def csv_text(rows: Iterable[Iterable[Any]]) -> str:
    """``rows`` as CSV text (the csv module's default dialect, ``\r\n`` line ends)."""
    import csv

    buf = io.StringIO(newline="")
    csv.writer(buf).writerows(rows)
    return buf.getvalue()


def hdf5_bytes(fill: Callable[[Any], None], *, format: str, format_version: int,
               base: bytes | None = None) -> bytes:
    """An HDF5 file built in memory: ``fill(h5py.File)`` adds the content.

    ``format``/``format_version`` are set as root attributes. With ``base``
    (the bytes of an existing file) the file is opened for update instead
    of created empty.
    """
    import h5py

    buf = io.BytesIO(base if base is not None else b"")
    with h5py.File(buf, "r+" if base is not None else "w") as f:
        fill(f)
        f.attrs["format"] = format
        f.attrs["format_version"] = int(format_version)
    return buf.getvalue()


def write_hdf5(path: str | Path, fill: Callable[[Any], None], *, format: str, format_version: int,
               what: str = "HDF5 file") -> Path:
    """Build an HDF5 file in memory with ``fill`` and write it atomically to ``path``."""
    data = hdf5_bytes(fill, format=format, format_version=format_version)
    return write_bytes(path, data, what=what)


def _text(v: Any) -> Any:
    return v.decode(errors="replace") if isinstance(v, bytes) else v


def check_format(attrs: Any, path: str | Path, *, format: str, version: int, what: str,
                 legacy: Iterable[str] = (), foreign_error: type[Exception] = StoreError) -> int:
    """The ``format_version`` of a file whose root attributes are ``attrs``.

    A file without ``format_version`` but with ``format`` equal to ``format``
    or one of the ``legacy`` names was written before versions existed: its
    layout is version 1. A foreign file raises ``foreign_error``, a newer
    version a :class:`StoreError` that says to upgrade stepnf.
    """
    fmt = _text(attrs.get("format"))
    if fmt != format and fmt not in tuple(legacy):
        shown = "missing" if fmt is None else repr(fmt)
        raise foreign_error(f"{path}: not a stepnf {what} (attribute 'format' is {shown}, "
                            f"expected {format!r})")
    raw = attrs.get("format_version")
    if raw is None:
        return 1
    try:
        found = int(raw)
    except (TypeError, ValueError):
        raise StoreError(f"{path}: {what} with an unreadable format_version {raw!r}") from None
    if found > version:
        raise StoreError(f"{path}: this {what} has format_version {found}, written by a newer stepnf; "
                         f"this stepnf reads format_version {version} or older: upgrade stepnf to read it")
    return found


def path_exists(path: str | Path) -> bool:
    """``Path.exists`` that says False where the path cannot even be looked up (a name too long, a loop)."""
    try:
        return Path(path).exists()
    except OSError:
        return False


def linked(folder: str | Path, names: Iterable[str]) -> Path | None:
    """The first of ``folder / name`` that is a symbolic link (where :func:`write_bytes` would refuse
    to write), or ``None``: a run checks its output names with it before computing anything."""
    for name in names:
        p = Path(folder) / name
        try:
            if p.is_symlink():
                return p
        except OSError:  # a name the file system cannot even look up: the writer says why
            continue
    return None


def check_folder(folder: str | Path) -> str | None:
    """Why no file can be written into ``folder`` (created if missing), or ``None`` if one can.

    Tried for real (a probe file created and removed), so a read-only mount,
    missing permissions (also for root on a read-only file system) and a path
    that is a file are all caught; a full disk is not (an empty file needs no
    space), that is found when writing.
    """
    folder = Path(folder)
    for p in (folder, *folder.parents):
        try:
            here = p.exists() or p.is_symlink()
        except OSError as exc:  # a name longer than the file system allows (ENAMETOOLONG), a loop
            return f"unusable path {p}: {reason(exc)}"
        if here:
            if not p.is_dir():
                return f"{p} is not a folder" + ("" if p == folder else f" (needed to create {folder})")
            break
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        return f"cannot create the folder {folder}: {reason(exc)}"
    probe = folder / f".stepnf-probe.{secrets.token_hex(4)}.tmp"
    try:
        fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except OSError as exc:
        return f"cannot write into the folder {folder}: {reason(exc)}"
    os.close(fd)
    try:
        os.unlink(probe)
    except OSError:
        pass
    return None

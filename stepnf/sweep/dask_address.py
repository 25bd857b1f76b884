"""Dask scheduler addresses: what ``[sweep.dask] scheduler`` and ``stepnf sweep --scheduler`` accept."""
from __future__ import annotations

import re
from pathlib import Path

from stepnf.errors import SceneError, StepnfError

#: The shape of an address before Dask parses it: an optional "scheme://", then no blank and no leading "/".
_ADDRESS = re.compile(r"^([a-z][a-z0-9+.-]*://)?[^\s/][^\s]*$")

#: Dask's network schemes a scheduler listens on.
SCHEMES = ("tcp", "tls", "ucx", "ws", "wss")


def check_scheduler(path: Path | None, key: str | None, address: str, prefix: str = "") -> str:
    """``address`` when Dask can dial it (``[scheme://]host:port``, a scheme of :data:`SCHEMES`), else a
    :class:`SceneError` naming ``key`` or starting with ``prefix`` (Dask's own parser decides: IPv6
    ``[::1]:8786`` included)."""
    why = None
    if not _ADDRESS.match(address):
        why = "blanks or a bare scheme"
    else:
        from distributed.comm.addressing import parse_address, parse_host_port

        try:
            scheme, loc = parse_address(address)
            parse_host_port(loc)
        except ValueError as exc:
            why = str(exc)
        else:
            if scheme not in SCHEMES:
                why = f"unknown scheme {scheme!r} (Dask's: {', '.join(SCHEMES)})"
    if why is not None:
        raise SceneError(path, key, f"{prefix}expected a scheduler address such as \"tcp://10.0.0.5:8786\" or "
                         f"\"10.0.0.5:8786\", got {address!r}: {why}")
    return address


def unreachable(path: Path | None, address: str, from_option: bool, exc: BaseException) -> StepnfError:
    """The error (exit 3) for a scheduler Dask could not connect to: names the sweep file ``path``, where the
    address came from (``[sweep.dask] scheduler`` or, ``from_option``, ``--scheduler``) and Dask's reason."""
    where = "--scheduler" if from_option else "[sweep.dask] scheduler"
    return StepnfError(f"{path or '<sweep>'}: {where} = {address!r}: no Dask scheduler answered there ({exc}); "
                       "start one there (`dask scheduler`), correct the address, or leave it out to run on this "
                       "machine")

"""The one matplotlib set-up of stepnf's figures (curves, Fig. 4, mode shapes).

matplotlib is optional and imported only when a figure is drawn (``import
stepnf`` never loads it). Figures are drawn with the non-interactive Agg
backend, so they work without a display, and saved as one atomic write
(:func:`stepnf.io.atomic.write_bytes`): a figure file is the complete new image
or the untouched previous one, and a failure (full disk) raises
:class:`stepnf.errors.OutputError`.
"""
from __future__ import annotations

import io
from pathlib import Path
from typing import Any

from stepnf.io.atomic import write_bytes

__all__ = ["pyplot", "save_figure"]


def pyplot() -> Any:
    """``matplotlib.pyplot`` on the non-interactive Agg backend (``ImportError`` without matplotlib).

    A program that imported pyplot first (a notebook, :func:`stepnf.run` in a script that plots) keeps
    the backend it chose: switching it would close that program's figures."""
    import sys

    import matplotlib

    if "matplotlib.pyplot" not in sys.modules:
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig: Any, path: str | Path, *, dpi: float) -> Path:
    """Write ``fig`` to ``path`` at ``dpi`` (format from the suffix, e.g. ``.png``), close it, return the path.

    The image is rendered in memory, the figure closed (also when rendering
    fails), then the bytes written atomically, missing folders created.
    """
    path = Path(path)
    try:
        buf = io.BytesIO()
        fig.savefig(buf, dpi=dpi, format=path.suffix[1:] or None)
    finally:
        pyplot().close(fig)
    write_bytes(path, buf.getbuffer(), what="figure")
    return path

"""The figure files of a run (``[output] plot``): ``NAME_modes.png``, ``NAME_backbone.png``, (masters on
manifolds of several modes) ``NAME_branches.png`` and (``[analysis.forcing]``) ``NAME_frc.png``, drawn the same
way for ``stepnf run`` and ``stepnf.run(..., output=...)``.

A figure that cannot be drawn (matplotlib missing, no memory left for it) or written (full disk) costs that
figure only: the results file is already written, and the reason is returned as a warning line for the
caller to show (the command line prints it on stderr, the Python API issues an
:class:`~stepnf.errors.OutputWarning`).
"""
from __future__ import annotations

from typing import Any

from stepnf.errors import OutputError
from stepnf.runtime.limits import short_of_memory

#: The figures of a run, in the order they are drawn.
SUFFIXES = ("modes", "backbone", "branches", "frc")


def draw_run_figures(scene: Any, result: Any) -> list[str]:
    """Draw the figures of ``result`` into ``scene.output_dir`` (each path added to ``result.extra_files``);
    returns the warning lines of the figures that could not be made. A :class:`RuntimeError` other than
    running out of memory is a bug and propagates."""
    from stepnf.io.atomic import reason

    warned = []
    for suffix in SUFFIXES:
        target = scene.output_dir / f"{scene.output_name}_{suffix}.png"
        try:  # the mode shapes (stepnf.report.mode_shapes), the DPIM backbones (stepnf.report.backbone_plot)
            from stepnf.report.backbone_plot import plot_backbones
            from stepnf.report.branches_plot import plot_branches
            from stepnf.report.frc_plot import plot_frcs
            from stepnf.report.mode_shapes import plot_mode_shapes

            draw = {"modes": plot_mode_shapes, "backbone": plot_backbones, "branches": plot_branches,
                    "frc": plot_frcs}[suffix]
            path = draw(result, target)
            if path is not None:
                result.extra_files.append(str(path))
        except (ImportError, MemoryError, RuntimeError) as exc:  # matplotlib missing, or no room for it
            if isinstance(exc, RuntimeError) and not short_of_memory(exc):
                raise
            warned.append(f"warning: no figure ({str(exc) or 'out of memory'})")  # results are there
        except (OSError, OutputError) as exc:  # full disk: the results file is written, the figure is not
            cause = exc.__cause__ if isinstance(exc, OutputError) and exc.__cause__ is not None else exc
            warned.append(f"stepnf: warning: no figure {target}: {reason(cause)}")
    return warned

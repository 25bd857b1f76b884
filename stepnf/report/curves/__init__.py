"""Type of nonlinearity versus the shell aspect ratio kappa: the paper's Figs. 2 and 3.

For the von Karman shell model (:class:`stepnf.models.VonKarmanShell`) on a grid of
``kappa = a^4 / (R^2 h^2)`` this computes, per master mode ``(k, n)`` (cos companion):

* ``T_p`` by NF (normal form, all modes of the model), MD and SMD (Table 1 of the
  paper, :mod:`stepnf.nf.evaluators`), in the model's normalisation (``int phi^2 dS = 1``
  over the unit disk, nondimensional time): ``w_NL = w_p (1 + T_p a^2)``;
* ``Gamma = T_p / max|phi_p|^2`` (``w_NL / w_p = 1 + Gamma (W_max / h)^2``, docs/design.md);
* ``rho_p`` (paper Eq. 8) and the mode it is attained for, as ``stepnf run`` computes it
  (:func:`stepnf.nf.diagnostics.slow_fast_ratio`): over the slave modes the master drives
  (``g^s_pp != 0``), degenerate twins excluded; at kappa = 0 (g = 0) over every non-twin
  mode, hence a jump between the first two grid values for modes such as (3,0);
* flags (bit field, :data:`FLAG_BITS`) naming why a value must not be trusted;

and the nondimensional frequencies of the first modes versus kappa (Fig. 2).

Flags and gaps. A method's value at one kappa is *flagged* when the evaluator reports an
internal resonance with a coupled mode (1:2 for NF, 1:1 for MD) within
``tolerances.resonance`` (the library's 5 % by default), when T is not finite, when
``|T|`` exceeds ``huge`` times the single-mode cubic scale ``T_cubic = 3 h_ppp / (8 w_p^2)``
(> 0 for every mode of the shell), or when the model does not hold every mode the master
couples to. A resonance makes a *gap* only when the frequency ratio is within
``gap_resonance`` (2 % by default) of 1:2 / 1:1 *and* the small-denominator terms change
T by more than ``significance * T_cubic``; otherwise it is recorded with bit
``NEAR_RESONANCE`` and the curve stays drawn. The narrower window is needed because the
shell's frequency ratios drift slowly with kappa: w(0,3)/w(0,2) stays within 5 % of 2 for
kappa in [32, 83], w(4,1)/w(2,1) for kappa in [2.5, 30], so the 5 % window would blank
most of those curves although T is finite and smooth there. Non-finite, huge and
incomplete values are always gaps. At a gap the stored data keep the value and its flag,
the plotted arrays (:meth:`Curves.plotted`) hold NaN, and the figure marks the point
with a tick at the bottom of the panel.

Data go to HDF5 (:func:`write_hdf5`) and CSV (:func:`write_csv`); figures to PNG with
matplotlib's Agg backend (:func:`plot_frequencies`, :func:`plot_nonlinearity`);
:func:`write_all` writes them all with the summary table (:func:`format_summary`).

Modules: :mod:`.data` (methods, quantities, flag bits, :class:`CurveOptions`,
:class:`Curves`), :mod:`.compute` (:func:`compute_curves` and the flags),
:mod:`.disagreement` (sign disagreements with NF, the summary), :mod:`.storage` (HDF5 and CSV files),
:mod:`.figures` (Figs. 2 and 3). Every public name is importable from here.
"""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

from stepnf.io.atomic import write_text
from stepnf.report.curves.compute import compute_curves, resonant_contribution
from stepnf.report.curves.data import (DEFAULT_MODES, FLAG_BITS, GAP_MASK, HUGE, INCOMPLETE, METHODS, NEAR_RESONANCE, NON_FINITE,
                   QUANTITIES, RES_1_1, RES_1_2, CurveOptions, Curves, CurvesError, check_quantity, parse_mode)
from stepnf.report.curves.disagreement import format_summary, sign_disagreements, summary
from stepnf.report.curves.figures import draw_nonlinearity, plot_frequencies, plot_nonlinearity
from stepnf.report.curves.storage import CURVES_FORMAT, CURVES_FORMAT_VERSION, read_hdf5, write_csv, write_hdf5

__all__ = ["DEFAULT_MODES", "METHODS", "QUANTITIES", "RES_1_2", "RES_1_1", "NEAR_RESONANCE", "NON_FINITE", "HUGE",
           "INCOMPLETE", "FLAG_BITS", "GAP_MASK", "CurvesError", "CurveOptions", "Curves", "compute_curves",
           "resonant_contribution", "parse_mode", "sign_disagreements", "summary", "format_summary",
           "CURVES_FORMAT", "CURVES_FORMAT_VERSION", "write_hdf5", "read_hdf5", "write_csv", "plot_frequencies",
           "plot_nonlinearity", "draw_nonlinearity", "write_all"]


def write_all(curves: Curves, out_dir: str | Path, quantities: Sequence[str] = QUANTITIES,
              plots: bool = True) -> dict[str, Path]:
    """HDF5, CSV, ``summary.txt`` and (``plots``) the PNGs of Fig. 2 and of Fig. 3 for each quantity."""
    d = Path(out_dir)
    files = {"hdf5": write_hdf5(curves, d / "curves.h5")}
    files["csv"], files["frequencies_csv"] = write_csv(curves, d)
    files["summary"] = write_text(d / "summary.txt", format_summary(curves) + "\n", what="summary")
    if plots:
        files["fig2"] = plot_frequencies(curves, d / "fig2_frequencies.png")
        for q in quantities:
            files[f"fig3_{check_quantity(q)}"] = plot_nonlinearity(curves, d / f"fig3_{q}.png", q)
    return files

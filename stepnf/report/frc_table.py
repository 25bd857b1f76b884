"""The peak table of the forced responses, printed under each master's backbone block (``stepnf run``, ``stepnf show``).

One line per forcing level (``[analysis.forcing]``, :mod:`stepnf.keys.forced`)::

    forced responses [0 -], xi = 0.01:
      level         peak A      Omega/w_p  W_max/h  folds  valid
      kappa 0.05    2.5000e+00  1.000123   -        0      yes

``peak A``: the largest amplitude of the master's modal coordinate (the top of the curve to ``0.125 xi^2``,
:func:`stepnf.forced.frc.measured`); ``Omega/w_p`` where it is reached (over the undamped linear frequency);
``W_max/h`` there where measured; ``folds``: the number of saddle-node points (jumps); ``valid``: whether the
peak lies within the backbone's validity range (``no``: the truncated series' number, not a forced response to
trust). Under a level's line: a peak outside the frequency range, an unstable peak with the largest stable
amplitude (``peak_stable``, a curve on a manifold of several modes), its isolas and what was found and not
followed. A master without a curve says why (``n/a``).
"""
from __future__ import annotations

from typing import Any

from stepnf.io.results import label_text


def _level(c: dict[str, Any]) -> str:
    if "kappa" in c:
        return f"kappa {float(c['kappa']):.4g}"
    return f"load {float(c['load']):.4g}"


def _f(x: Any, fmt: str) -> str:
    return "-" if x is None else fmt.format(float(x))


def frc_lines(mode: Any) -> list[str]:
    """The lines of master ``mode``'s forced responses (a :class:`~stepnf.io.results.ModeResult`); none when the
    run computed none."""
    frc = getattr(mode, "frc", None)
    if frc is None:
        return []
    head = f"forced responses [{mode.index} {label_text(mode.label)}]"
    reason = getattr(mode, "frc_reason", None)
    if reason is not None or not frc:
        return [f"{head}: n/a ({reason or 'no curve'})"]
    xi = frc[0].get("xi")
    out = [f"{head}{'' if xi is None else f', xi = {float(xi):.4g}'}:",
           "  " + "  ".join(["level".ljust(12), "peak A".ljust(11), "Omega/w_p".ljust(10), "W_max/h".ljust(8),
                             "folds", "valid"])]
    w = float(mode.omega)
    for c in frc:
        pk = c.get("peak") or {}
        W = pk.get("Omega")
        valid = pk.get("valid")
        cells = [_level(c).ljust(12), _f(pk.get("amplitude"), "{:.4e}").ljust(11),
                 _f(None if W is None else float(W) / w, "{:.6f}").ljust(10),
                 _f(pk.get("w_max_h"), "{:.4g}").ljust(8), str(len(c.get("folds") or [])).ljust(5),
                 "-" if valid is None else "yes" if valid else "no (beyond the backbone's validity)"]
        out.append(("  " + "  ".join(cells)).rstrip())
        out += [f"    {_level(c)}: {note}" for note in _notes(c, w)]
    return out


def _notes(c: dict[str, Any], w: float = 1.0) -> list[str]:
    """What the line of one level does not say: a peak outside ``frequency_range`` (not on the curve), isolas
    (closed curves of their own, drawn), the branch points of a curve on a manifold of several modes (where a
    coupled branch is born), what was found and not followed (the curve's ``flags``)."""
    out = []
    bps = c.get("branch_points") or []
    if bps:
        at = ", ".join(f"{float(b['Omega']) / w:.6f}" for b in bps)
        out.append(f"branch point(s) at Omega/w_p = {at} (manifold {c.get('manifold')}): coupled branch(es) drawn")
    if c.get("peak_outside_range"):
        out.append("peak outside [analysis.forcing] frequency_range (not on the curve drawn)")
    if "peak_stable" in c:
        ps = c["peak_stable"]
        out.append("peak unstable; no stable point on the curve" if ps is None else
                   f"peak unstable; stable peak A = {float(ps['amplitude']):.4e} at Omega/w_p = "
                   f"{float(ps['Omega']) / w:.6f} (segment {int(ps.get('segment', 0))})")
    if c.get("isolas"):
        out.append(f"{int(c['isolas'])} isola(s): closed curve(s) apart from the main one")
    return out + [str(f) for f in c.get("flags") or []]

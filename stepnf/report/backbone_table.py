"""The backbone block printed under the main table (``stepnf run`` and ``stepnf show``), one per master mode.

Each line gives A, w_NL / w and, where known, W_max / h; a line beyond the validity limit (orders N-2
and N differ by more than the tolerance) ends with ``beyond validity``: its numbers are not to be
trusted as a backbone, only as what the truncated series gives. Without a list of amplitudes in the
scene, a few points of the grid are shown (the JSON document and the HDF5 file keep all of them).
"""
from __future__ import annotations

from typing import Any

from stepnf.dpim.backbone_report import beyond_validity
from stepnf.flags import NO_VALIDITY_REASONS
from stepnf.io.results import RunResult, label_text
from stepnf.report.frc_table import frc_lines

#: Grid points shown per mode when the scene gives no list.
SHOWN = 6


def _rows(block: dict[str, Any]) -> list[int]:
    n = len(block["amplitude"])
    if not block.get("grid") or n <= SHOWN:
        return list(range(n))
    step = (n - 1) / (SHOWN - 1)
    return sorted({round(i * step) for i in range(SHOWN)})


def _f(x: Any, fmt: str) -> str:
    return "-" if x is None else fmt.format(float(x))


def backbone_lines(res: RunResult) -> list[str]:
    """The lines of every mode's backbone block (none when the run computed no backbone)."""
    out: list[str] = []
    for m in res.modes:
        b = m.backbone
        if not b:
            continue
        out.append(f"backbone [{m.index} {label_text(m.label)}] order {b['order']}, {limit_text(b)}:")
        out += manifold_lines(b, m.index)
        wh = b.get("w_max_over_h")
        if b["amplitude"]:  # (a DPIM that refused the master has none)
            out.append(("  " + "  ".join(["A".ljust(11), "w_NL/w".ljust(10)] + (["W_max/h"] if wh else []))).rstrip())
        for i in _rows(b):
            A = b["amplitude"][i]
            cells = [_f(A, "{:.4e}").ljust(11), _f(b["omega_ratio"][i], "{:.6f}").ljust(10)]
            if wh:
                cells.append(_f(wh[i], "{:.4f}").ljust(9))
            line = "  " + "  ".join(cells)
            if b["omega_ratio"][i] is None:
                line += "  not reached by the parametrisation"
            elif beyond_validity(b, A):
                line += "  beyond validity"
            out.append(line.rstrip())
        out += flag_lines(b.get("flags", []))
        out += frc_lines(m)  # the peaks of its forced responses, if any
    return out


def manifold_lines(b: dict[str, Any], p: int) -> list[str]:
    """A master on a manifold of several modes (:mod:`stepnf.dpim.manifold_report`): which manifold and why, and
    one line per coupled branch of master ``p`` (its amplitude range, how much of it is stable); none for a
    single-mode block."""
    man = b.get("manifold")
    if not man:
        return []
    k = ":".join(map(str, man["ratios"])) if man.get("ratios") else "none"
    out = [f"  on the manifold of modes {man['modes']} ({man.get('chosen')}: {man.get('why')}): ratios {k}, "
           f"{man.get('resonant_monomials')} resonant monomials kept"]
    for c in b.get("coupled_branches", []):
        j = c["masters"].index(p) if p in c["masters"] else 0
        amps = [a for a in c["A"][j] if a is not None]
        stable = sum(c["stable"]) / max(len(c["stable"]), 1)
        out.append(f"  coupled branch: Omega {c['Omega'][0]:.6g} .. {c['Omega'][-1]:.6g}, A of mode {c['masters'][j]} "
                   f"{min(amps):.4g} .. {max(amps):.4g}, {100 * stable:.0f}% of its points stable, {_valid(c)}")
    return out


def _valid(c: dict[str, Any]) -> str:
    """Where a coupled branch (traced past it) is valid, in the A of its master: orders N-2 and N
    (:func:`stepnf.dpim.multimode.backbone.validity`)."""
    v, why = c.get("valid_up_to"), c.get("valid_reason")
    if v is not None:
        return f"valid up to A = {float(v):.4g} ({why}); traced beyond"
    return "orders agree over the range traced" if why == "not reached" else f"no validity range ({why})"


def limit_text(b: dict[str, Any]) -> str:
    """What the block says of its validity limit (``valid_up_to``, ``valid_reason``)."""
    v, orders = b.get("valid_up_to"), f"orders {b['order'] - 2} and {b['order']}"
    if b.get("failed"):
        return "FAILED, not computed (flag below; the command exits 3)"
    if b.get("valid_reason") == "forces inaccurate":
        return "no validity range: the forces at the probe amplitude are not accurate (flag below)"
    if b.get("valid_reason") == "no continuing branch":  # a master on a manifold, at an exact resonance
        return "no branch of its manifold continues the linear mode (exact resonance): its coupled branches follow"
    if b.get("valid_reason") in NO_VALIDITY_REASONS:
        return f"no validity range: {b['valid_reason']} (flag below)"
    if v is None:
        return f"{orders} agree over the range searched"
    tol = float(b["tolerance"])
    return (f"valid up to A = {float(v):.4g} ({orders} within {tol:.0e} in frequency, {tol ** 0.5:.1g} in shape; "
            f"{b.get('valid_reason', 'orders differ')} there)")


def flag_lines(flags: list[dict[str, Any]]) -> list[str]:
    """The block's flags: the internal resonances on one line (harmonic m: the modes near m w_p), the
    others by their message (the JSON document keeps every message)."""
    near: dict[int, list[str]] = {}
    lines = []
    for f in flags:
        if str(f.get("kind", "")).startswith("internal_resonance_1_") and f.get("harmonic") is not None:
            near.setdefault(int(f["harmonic"]), []).append(str(f.get("mode")))
        else:
            lines.append(f"  flag: {f['message']}")
    if near:
        parts = [f"{m} w_p: mode{'s' if len(v) > 1 else ''} {', '.join(v)}" for m, v in sorted(near.items())]
        lines.insert(0, "  flag: internal resonances (small denominators) near " + "; ".join(parts))
    return lines

"""The human-readable table printed by ``stepnf run``."""
from __future__ import annotations

import math

from stepnf.report.backbone_table import backbone_lines
from stepnf.flags import gamma_unusable, na_hint, printed_under_table, t_unusable
from stepnf.runtime.printable import printable
from stepnf.io.results import RunResult, label_text


#: Gamma's format: four significant digits, whatever its size (a cantilever's 1e-5 as well as a plate's 0.27)
GAMMA_FORMAT = "{:+.4g}"


def _num(x: float | None, fmt: str = "{:+.4e}") -> str:
    if x is None:
        return "-"
    if isinstance(x, float) and math.isinf(x):
        return "+inf" if x > 0 else "-inf"
    return fmt.format(x)


def format_table(res: RunResult) -> str:
    """One row per master mode and method: T, Gamma, behaviour, rho, flags.

    A T the tool knows to be wrong (:func:`stepnf.flags.t_unusable`: infinite, a master without a
    single-mode manifold, a truncated modal sum, forces too inaccurate) is shown as ``n/a``, with its
    Gamma and behaviour, and the reason is printed under the table; the JSON document and the HDF5
    file keep the number. A Gamma alone is n/a when a flag says so (:func:`stepnf.flags.gamma_unusable`:
    a mode the transverse direction barely carries), with a ``Gamma n/a`` line; Gamma is printed with
    four significant digits. Which flags get a line of their own: :mod:`stepnf.flags`.
    """
    lines = []
    head = res.model.get("adapter") or res.model.get("model") or ""
    kappa = f"   kappa = {res.kappa:.4g}" if res.kappa is not None else ""
    lines.append(f"stepnf: {res.scene.get('solver')} {head}{kappa}")
    has_gamma = any(r.gamma is not None for m in res.modes for r in m.methods.values())
    cols = ["mode", "label", "omega", "w_bar", "rho", "method", "T", "Gamma" if has_gamma else None,
            "behaviour", "flags"]
    cols = [c for c in cols if c]
    rows, unusable, no_gamma = [], [], []
    for m in res.modes:
        first = True
        for name, r in m.methods.items():
            flags = ", ".join(sorted({f["kind"] + (f" (mode {f['mode']})" if f.get("mode") is not None else "")
                                      for f in r.flags + (m.flags if first else [])}))
            row = [str(m.index) if first else "", label_text(m.label) if first else "",
                   _num(m.omega, "{:.6g}") if first else "",
                   _num(m.omega_bar, "{:.4f}") if first else "",
                   _num(m.rho, "{:.3f}") if first else ""]
            verdict = t_unusable(r)
            if verdict:
                unusable.append((m.index, name, verdict))
                row += [name, "n/a"] + (["n/a"] if has_gamma else []) + ["n/a", flags or "-"]
            else:
                gamma_na = gamma_unusable(r) if r.gamma is not None else None
                if gamma_na:
                    no_gamma.append((m.index, name, gamma_na))
                row += [name, _num(r.T)] + (["n/a" if gamma_na else _num(r.gamma, GAMMA_FORMAT)] if has_gamma else [])
                row += [r.behaviour, flags or "-"]
            rows.append(row)
            first = False
    widths = [max(len(c), *(len(r[i]) for r in rows)) if rows else len(c) for i, c in enumerate(cols)]
    lines.append("  ".join(c.ljust(w) for c, w in zip(cols, widths)))
    lines.append("  ".join("-" * w for w in widths))
    lines += ["  ".join(v.ljust(w) for v, w in zip(r, widths)) for r in rows]
    c = res.counts
    lines.append(f"counts: {c.get('force_evaluations', 0)} force evaluations, {c.get('linear_solves', 0)} "
                 f"linear solves, {c.get('factorizations', 0)} factorizations"
                 f"; total {res.timings.get('total', 0.0):.2f} s")
    for f in res.flags:
        lines.append(f"note: {f['message']}")
    said = {(i, name): verdict for i, name, verdict in unusable}
    grouped: dict[tuple[int, str], list[str]] = {}  # one line per mode and reason (a master-wide one: every method)
    for i, name, (_, reason) in unusable:
        grouped.setdefault((i, reason), []).append(name)
    for (i, reason), names in grouped.items():
        lines.append(f"n/a [{i} {', '.join(names)}]: {reason} (the JSON document and the HDF5 file keep the number)")
    for kind in dict.fromkeys(kind for _, _, (kind, _) in unusable):  # once per kind of n/a
        if na_hint(kind):
            lines.append(f"hint: {na_hint(kind)}")
    gamma_grouped: dict[tuple[int, str], list[str]] = {}
    for i, name, reason in no_gamma:
        gamma_grouped.setdefault((i, reason), []).append(name)
    for (i, reason), names in gamma_grouped.items():
        lines.append(f"Gamma n/a [{i} {', '.join(names)}]: {reason} (the JSON document and the HDF5 file keep "
                     "the number)")
    for m in res.modes:
        for name, r in m.methods.items():
            for f in r.flags:
                kind, reason = said.get((m.index, name), ("", ""))
                if not printed_under_table(f) or f.get("kind") == kind or str(f.get("message")) in reason:
                    continue  # not a line of its own, or said by its n/a line
                lines.append(f"flag [{m.index} {r.method}]: {f['message']}")
    lines += backbone_lines(res)
    if res.hdf5_path:
        lines.append(f"results: {res.hdf5_path}")
    for p in res.extra_files:
        lines.append(f"{'figure' if str(p).endswith('.png') else 'fields'}: {p}")
    return printable("\n".join(lines))  # names, labels and messages may come from a received file

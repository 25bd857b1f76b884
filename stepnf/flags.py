"""The one catalogue of flag kinds: what each says, where it is printed, and which numbers it makes n/a.

A flag is a dict ``{"kind": ..., "message": ..., optional "mode", "value", ...}`` attached to a
method's result (``MethodResult.flags``), to a master mode (``ModeResult.flags``), to a backbone
block (``modes[i].backbone.flags``) or to the run (``RunResult.flags``). Every module builds its flags
with :func:`new_flag`, which refuses a kind not declared here (``tests/nf/test_flags.py`` also checks the
sources). Each kind is declared with

* ``printed``: where the table shows its message: ``"line"`` (a ``flag [p method]: ...`` line
  under the table), ``"note"`` (a ``note: ...`` line, run flags), ``"block"`` (in the backbone
  block), ``"column"`` (its kind in the flags column only, the JSON document keeps the message);
* ``t_na``: whether it makes T (and Gamma, behaviour) n/a in the table: ``"always"``, ``"never"``,
  or ``"value"`` (:func:`t_unusable` compares the flag's ``value``, or a resonance's ``ratio``, with
  its threshold);
* ``backbone_invalid``: whether the master's backbone gets no validity range when a method of
  that master carries it;
* ``gamma_na``: whether it makes Gamma (alone: T stays) n/a in the table (:func:`gamma_unusable`);
* ``names_mode``: whether it carries the index of the mode it concerns (``"mode"``);
* ``template``: the gist of its message (the emitting module writes the message itself, with numbers).

The printed table is the only place that hides a number: the JSON document and the HDF5 file keep
T and record its flags, and each method's ``na`` entry gives the reason the table shows n/a
(:func:`t_unusable`). A number that is infinite (a method that diverges) is always n/a, whatever its
flags say; JSON has no infinity, so such a number is stored as the string ``"inf"``/``"-inf"``
(:func:`json_safe`), never as ``Infinity``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Iterable, Mapping

#: Below this share of G(phi_p, phi_p) carried by the retained modes, a modal-sum T is n/a.
TRUNCATION_UNUSABLE = 0.5
#: At or above this relative change of T between the two STEP amplitudes, T is n/a.
STEP_UNUSABLE = 1.0
#: A 1:k internal resonance whose ratio ``w_s / w_p`` is within this (relative) of ``k`` is exact as far as
#: the computed frequencies can tell: an eigen-solve resolves eigenvalues to ~1e-12 relative at best (ARPACK's
#: tolerance here) and 3D shell models to ~1e-8 (two runs' Gamma of the same mode agree to that), so a
#: smaller detuning is round-off and the T it gives (1e14 for an exact 1:2 built in floating point) is a
#: divergence, not a number of the structure.
RESONANCE_EXACT = 1e-8


@dataclass(frozen=True)
class FlagKind:
    """One kind of flag (module docstring)."""

    name: str
    printed: str
    t_na: str = "never"
    backbone_invalid: bool = False
    names_mode: bool = False
    template: str = ""
    #: with ``backbone_invalid``: the backbone block's ``valid_reason`` (its ``valid_up_to`` is then 0)
    backbone_reason: str = ""
    #: whether it makes Gamma (only Gamma: T stays) n/a in the table (:func:`gamma_unusable`)
    gamma_na: bool = False
    #: what the user may try when it makes T n/a: a ``hint:`` line under the table (:func:`na_hint`)
    hint: str = ""


_KINDS = (
    FlagKind("internal_resonance_1_2", "line", t_na="value", names_mode=True,
             template="{method}: mode s is in 1:2 internal resonance with master mode p (w_s/w_p = r); the "
                      "normal form has a small denominator there (exactly 2: it diverges, T = +-inf)"),
    FlagKind("internal_resonance_1_1", "line", t_na="value", names_mode=True,
             template="{method}: mode s (a degenerate twin) couples to master mode p: the modal derivative "
                      "diverges"),
    FlagKind("internal_resonance_1_m", "block", names_mode=True,
             template="DPIM: mode s is near m w_p (harmonic m of the parametrisation): a small denominator"),
    FlagKind("manifold_small_denominator", "block", names_mode=True,
             template="DPIM manifold: mode s, outside the manifold, is near a combination of the masters' "
                      "frequencies that a monomial of the parametrisation has: a small denominator"),
    FlagKind("manifold_no_own_branch", "block",
             template="no periodic orbit of the manifold's reduced dynamics continues master mode p's linear mode "
                      "(an exact resonance: the coupled branches take its place); its backbone has no amplitudes"),
    FlagKind("diverges", "line", t_na="always",
             template="T is infinite: the method meets a zero denominator (the verdict of :func:`t_unusable` for "
                      "a T that is not finite, whatever the method's flags; no module emits it as a flag)"),
    FlagKind("modal_truncation", "line", t_na="value",
             template="{method}: the n retained modes carry only x% of G(phi_p, phi_p)"),
    FlagKind("step_accuracy", "line", t_na="value",
             template="T (or STEP's G, h) changes by x (relative) between the two STEP amplitudes",
             hint="T depends on the STEP amplitude: at a small amplitude the solver's force digits do not resolve "
                  "the nonlinear forces (the calculix adapter's .dat forces carry 7). Try a larger [analysis.step] "
                  "relative_amplitude (a multiple of the thickness or characteristic length: e.g. 5, then 20; the "
                  "two amplitudes should agree), or [analysis.step] method = \"tangent\" where the solver offers "
                  "tangent stiffnesses (calculix does). A force that is not an exact cubic (a shell's) changes the "
                  "other way, as amplitude^2: then a smaller amplitude (see step_unconverged)"),
    FlagKind("t_roundoff", "line", t_na="value",
             template="rounding leaves T an error of up to x (relative): the forces' rounding and the solves "
                      "through the cancellation of T's terms (a slender structure), and the master's own eigenvalue "
                      "error through T's slope in it (stepnf.nf.roundoff.roundoff_message says which)",
             hint="T is a small difference of large terms here (a slender structure). The part from the forces' "
                  "rounding falls as 1/amplitude^2: set a larger [analysis.step] relative_amplitude (e.g. 20, then "
                  "100; a solid model's force is an exact cubic, a large amplitude costs nothing), or leave both "
                  "amplitude keys out and stepnf raises it itself. The part from the mode's own eigenvalue (the "
                  "message names it) no amplitude reduces: it is the conditioning of K in double precision; a "
                  "better-conditioned mesh of the same structure (bricks rather than tetrahedra, fewer elements "
                  "through the thickness) or a shell model reduces it"),
    FlagKind("step_extrapolated", "line", names_mode=True,
             template="STEP of mode p: the force is not an exact cubic (G, h change as q^rate over three "
                       "amplitudes): the values kept are Richardson extrapolations of the cubic fit"),
    FlagKind("step_unconverged", "line", names_mode=True,
             template="STEP's cubic fit of mode p is not converged: G or h changes at a rate that is not the cubic "
                      "fit's q^2, or keeps an error x above the tolerance after extrapolation"),
    FlagKind("non_conservative", "line",
             template="master mode p: the internal force is not the gradient of an energy: phi_p.G(phi_p, y) and "
                      "y.G(phi_p, phi_p) differ by x (relative; y the static condensation of G(phi_p, phi_p)): nf, "
                      "dnf, md, smd take them equal, the DPIM does not (stepnf.pipeline.conservative)"),
    FlagKind("step_amplitude_raised", "line",
             template="rounding left T too few digits: STEP again at k x the amplitude, the better T kept"),
    FlagKind("manifold_probe", "line",
             template="STEP along the quadratic manifold gives T = x with a rounding bound e; the better T kept"),
    FlagKind("twin_driven", "line", t_na="always", backbone_invalid=True, names_mode=True,
             backbone_reason="no single-mode manifold (a degenerate twin is driven)",
             template="mode t, a degenerate twin of master mode p, is driven by its nonlinear forces: a "
                      "single-mode invariant manifold does not exist"),
    FlagKind("rigid_mode_driven", "line", t_na="always", backbone_invalid=True,
             backbone_reason="no periodic orbit (a rigid mode is driven)",
             template="master mode p drives the zero-frequency mode r: its motion drifts, no periodic orbit"),
    FlagKind("ill_conditioned", "note",
             template="a mode's eigenvalue is resolved only to x (relative: eps |phi|^T |K| |phi| / lambda, or its "
                      "distance to its vector's Rayleigh quotient)"),
    FlagKind("unresolved_mode", "line", t_na="always", backbone_invalid=True, names_mode=True,
             backbone_reason="the master's eigenvalue is not resolved in double precision",
             template="master mode p's eigenvalue is resolved only to x (beyond 1%): T is n/a"),
    FlagKind("soft_modes_counted_rigid", "note", template="modes counted as rigid may be soft elastic modes"),
    FlagKind("fewer_modes", "note", template="only n elastic modes available for the modal sums"),
    FlagKind("no_gamma", "note", template="why Gamma is not given"),
    FlagKind("no_length", "note", template="the model gives no characteristic length"),
    FlagKind("resonance_check_partial", "block",
             template="the computed modes stop below N w_p: higher resonances unchecked"),
    FlagKind("resonance_check_skipped", "block", template="no spectrum: resonances not checked"),
    FlagKind("backbone_fold", "block", template="the amplitude A(rho) stops growing"),
    FlagKind("backbone_unreached", "block", template="the parametrisation never reaches an amplitude asked"),
    FlagKind("backbone_twin", "block", names_mode=True, template="the backbone is that of the cos twin"),
    FlagKind("backbone_failed", "block",
             template="the DPIM of the master failed (a numerical error, unusable forces): no backbone, "
                      "T and the rest of the run kept, the command exits 3"),
    FlagKind("gamma_not_transverse", "column", gamma_na=True,
             template="the transverse direction carries x% (< GAMMA_SHARE_MIN) of the mode's kinetic energy: Gamma "
                      "refers to a displacement the mode barely has"),
)
#: kind name -> :class:`FlagKind`
CATALOGUE: dict[str, FlagKind] = {k.name: k for k in _KINDS}


def kind_of(flag: Mapping[str, Any]) -> FlagKind | None:
    """The catalogue entry of ``flag`` (``internal_resonance_1_m`` for the DPIM's harmonics m >= 3;
    1 and 2 are their own kinds); None for a kind the catalogue does not know (an old file's)."""
    name = str(flag.get("kind", ""))
    if name in CATALOGUE:
        return CATALOGUE[name]
    if name.startswith("internal_resonance_1_") and name[len("internal_resonance_1_"):].isdigit():
        return CATALOGUE["internal_resonance_1_m"]
    return None


def is_known(name: str) -> bool:
    """Whether the flag kind ``name`` is declared (:func:`kind_of`)."""
    return kind_of({"kind": name}) is not None


class FlagKindError(LookupError):
    """A flag of a kind this catalogue does not declare: a bug in stepnf (an internal error), never the user's."""


def new_flag(kind: str, **fields: Any) -> dict[str, Any]:
    """The flag ``{"kind": kind, **fields}``, its keys in the order given; every module builds its flags with it,
    so a kind cannot be misspelt: one the catalogue does not declare (:func:`is_known`) is a
    :class:`FlagKindError`."""
    if not is_known(kind):
        raise FlagKindError(f"flag kind {kind!r} is not declared in stepnf.flags; declared: {sorted(CATALOGUE)}")
    return {"kind": kind, **fields}


def printed_under_table(flag: Mapping[str, Any]) -> bool:
    """Whether the table prints ``flag``'s message on a line of its own under the table."""
    k = kind_of(flag)
    return k is not None and k.printed == "line"


def _finite(x: Any) -> bool:
    try:
        return math.isfinite(float(x))
    except (TypeError, ValueError):
        return False


def _value(flag: Mapping[str, Any]) -> float | None:
    v = flag.get("value")
    if isinstance(v, str) and v in ("inf", "-inf"):
        return float(v)
    try:
        return None if v is None or isinstance(v, bool) else float(v)
    except (TypeError, ValueError):
        return None


def t_unusable(r: Any) -> tuple[str, str] | None:
    """``(kind, reason)`` when the table must show ``r.T`` (a :class:`stepnf.nf.coefficient.MethodResult`) as
    n/a, else None. The reasons, in this order: T infinite or NaN (the method diverges); a flag whose
    kind is ``t_na = "always"``; the retained modes carry less than :data:`TRUNCATION_UNUSABLE` of
    G(phi_p, phi_p) (``r.extra["captured_fraction"]`` or the ``modal_truncation`` flag's value); the
    rounding bound of T (``t_roundoff`` flag's value, :mod:`stepnf.nf.roundoff`) is :data:`STEP_UNUSABLE`
    or more; T changes by :data:`STEP_UNUSABLE` or more between the two STEP amplitudes (``r.T_error`` or
    the ``step_accuracy`` flag's value)."""
    flags = [f for f in (r.flags or []) if isinstance(f, Mapping)]
    if not _finite(r.T):
        why = next((f for f in flags if kind_of(f) is not None and kind_of(f).name.startswith("internal_resonance")),
                   None)
        cause = f": {why['message']}" if why is not None and why.get("message") else ""
        return ("diverges", f"T is {r.T} (the method diverges: a zero denominator){cause}")
    for f in flags:
        k = kind_of(f)
        if k is not None and k.t_na == "always":
            return (k.name, str(f.get("message") or k.template))
    for f in flags:
        order = {"internal_resonance_1_1": 1.0, "internal_resonance_1_2": 2.0}.get(str(f.get("kind")))
        ratio = _value({"value": f.get("ratio")})
        if order is not None and ratio is not None and abs(ratio - order) <= RESONANCE_EXACT * order:
            return ("diverges", f"w_s/w_p = {order:g} to within {RESONANCE_EXACT:g} (round-off): the method divides "
                                f"by a detuning the frequencies do not resolve, T = {float(r.T):.3e} is not a number "
                                f"of the structure: {f.get('message', '')}")
    frac = r.extra.get("captured_fraction") if isinstance(r.extra, Mapping) else None
    if frac is None:
        values = [_value(f) for f in flags if f.get("kind") == "modal_truncation"]
        values = [v for v in values if v is not None]
        frac = min(values) if values else None
    if frac is not None and float(frac) < TRUNCATION_UNUSABLE:
        n = f"the {r.retained_modes} retained modes" if r.retained_modes else "the retained modes"
        return ("modal_truncation",
                f"{n} carry {100 * float(frac):.2g}% of G(phi_p, phi_p): the modal sum misses the rest")
    for f in flags:
        v = _value(f) if f.get("kind") == "t_roundoff" else None
        if v is not None and v >= STEP_UNUSABLE:
            size = f"up to {100 * v:.3g}%" if math.isfinite(v) else "larger than T itself (T = 0 within it)"
            return ("t_roundoff", f"rounding leaves T an error {size}: not even its sign is established"
                                  + (f" ({f['message']})" if f.get("message") else ""))
    err = r.T_error
    if err is None:
        values = [_value(f) for f in flags if f.get("kind") == "step_accuracy" and f.get("mode") is None]
        values = [v for v in values if v is not None]
        err = max(values) if values else None
    if err is not None and float(err) >= STEP_UNUSABLE:
        return ("step_accuracy", f"T changes by {100 * float(err):.3g}% between the two STEP amplitudes: "
                                 "not even its sign is established")
    return None


def na_hint(kind: str) -> str:
    """The ``hint`` of flag kind ``kind`` (what to try when it makes T n/a); '' when it has none."""
    k = CATALOGUE.get(kind)
    return k.hint if k is not None else ""


def gamma_unusable(r: Any) -> str | None:
    """Why the table must show ``r.gamma`` (a :class:`stepnf.nf.coefficient.MethodResult`) as n/a while T stays:
    the message of its first flag whose kind is ``gamma_na``; None otherwise (T's own n/a,
    :func:`t_unusable`, takes Gamma with it)."""
    for f in r.flags or []:
        k = kind_of(f) if isinstance(f, Mapping) else None
        if k is not None and k.gamma_na:
            return str(f.get("message") or k.template)
    return None


def backbone_invalidating(flags: Iterable[Mapping[str, Any]]) -> dict | None:
    """The first of ``flags`` whose kind takes every validity range from the master's backbone, or None."""
    for f in flags:
        k = kind_of(f)
        if k is not None and k.backbone_invalid:
            return dict(f)
    return None


#: ``valid_reason`` of a backbone whose DPIM stopped at a singular ``K - (m w)^2 M`` (exact 1:m resonance)
DIVERGES_REASON = "the parametrisation diverges (a mode at exactly a harmonic of the master)"
#: ``valid_reason`` of a backbone whose DPIM failed (a numerical error: the block's ``failed_reason`` says which)
BACKBONE_FAILED_REASON = "the backbone failed (a numerical error in its DPIM)"
#: ``valid_reason`` of a backbone block that has no validity range at all (its ``valid_up_to`` is 0)
NO_VALIDITY_REASONS = ("forces inaccurate", DIVERGES_REASON, BACKBONE_FAILED_REASON) + tuple(
    k.backbone_reason for k in _KINDS if k.backbone_invalid)


def json_safe(x: Any) -> Any:
    """``x`` (a flag, a list of flags, any JSON-like value) with every infinite float as the string
    ``"inf"``/``"-inf"`` and every NaN as None: ``json.dumps(..., allow_nan=False)`` then never fails and
    no ``Infinity`` is ever written. Numpy scalars become Python numbers."""
    if isinstance(x, Mapping):
        return {str(k): json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [json_safe(v) for v in x]
    if isinstance(x, bool) or x is None or isinstance(x, str):
        return x
    if hasattr(x, "item") and callable(x.item) and getattr(x, "shape", None) == ():
        x = x.item()
    if isinstance(x, float):
        if math.isnan(x):
            return None
        if math.isinf(x):
            return "inf" if x > 0 else "-inf"
    return x

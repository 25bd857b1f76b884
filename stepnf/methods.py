"""The one table of methods that compute T: what a scene calls each, how it is printed, what it needs.

A scene's ``analysis.methods`` lists names of :data:`TABLE`; each name is also the key of the method's
result (``modes[i].methods[name]`` in the JSON document, ``modes/mode_<p>/<name>`` in the HDF5 file).
Four methods, each at two orders:

* NF, the normal form (``nf``: modal sums over the retained modes) and DNF, the direct normal form
  (``dnf``: the same at full order, from two solves on the mesh: ``K^+ Gv`` and ``(K - 4 w_p^2 M) z = b``);
* MD and SMD, quadratic manifolds with modal derivatives and static modal derivatives
  (``md_modal``, ``smd_modal``: modal sums; ``md_full``, ``smd_full``: bordered solve with
  ``K - w_p^2 M``, solve with ``K^+``). ``md`` and ``smd`` name no order of their own: they follow
  ``analysis.qm_order`` (:meth:`Method.resolve`).

The *evaluator* of a name is the method it resolves to (``md`` -> ``md_full`` or ``md_modal``); only
evaluators compute. A modal-order evaluator needs the modal coefficients ``g^s_pp``, ``h^p_ppp`` over
the retained modes (from the targeted STEP projected on the modes, or from the full STEP plan with
``analysis.tensors = "full"``); a full-order one needs ``G(phi_p, phi_p)`` on the mesh (the targeted
STEP) and the full-order linear algebra (:attr:`Method.factorises`). On a model given in modal
coordinates (:class:`~stepnf.plugin.modal_model.ModalModel`) every method is defined: a full-order one
is computed as its modal variant over every mode of the model (:attr:`Method.modal`).

Nothing heavy is imported here (``import stepnf`` stays light): the function that computes an
evaluator is named by its dotted path and imported on first use (:meth:`Method.function`).

A new method: its function in :mod:`stepnf.nf` (a modal one takes ``(p, omega, g, h, S, *, tol, labels,
floor)`` like :func:`~stepnf.nf.evaluators.nf_modal`), one :class:`Method` in the table below (the scene
check, the STEP plan and the deflated solves read it from there), and, at full order, its run on the mesh
in :data:`stepnf.pipeline.apply_method.FULL_RUNS`.
"""
from __future__ import annotations

from dataclasses import dataclass
from importlib import import_module
from typing import Callable, Iterable

#: The names a scene may write (each the key of its stored result).
NF, DNF, MD, SMD = "nf", "dnf", "md", "smd"
MD_MODAL, SMD_MODAL, MD_FULL, SMD_FULL = "md_modal", "smd_modal", "md_full", "smd_full"
#: ``analysis.qm_order``: the orders a method is computed at.
MODAL, FULL = "modal", "full"
ORDERS = (FULL, MODAL)
#: The STEP terms every method needs: T combines the quadratic (G) and cubic (H) terms.
TERMS = ("quadratic", "cubic")
#: ``analysis.methods`` when the scene does not say.
DEFAULT_METHODS = (NF, DNF, MD, SMD)

_EVALUATORS = "stepnf.nf.evaluators"


@dataclass(frozen=True)
class Method:
    """One entry of :data:`TABLE` (module docstring)."""

    #: the name as the scene writes it, and the key of its result
    name: str
    #: how messages print it ("DNF's T changes by ...")
    label: str
    #: ``"modal"`` or ``"full"``; None: follows ``analysis.qm_order`` (``md``, ``smd``)
    order: str | None
    #: its modal-order variant (what it computes on a modal model) and its full-order variant
    modal: str
    full: str
    #: dotted path of the function that computes it; None for a name that only resolves to another
    evaluator: str | None = None
    #: the STEP terms it needs (:data:`TERMS`)
    terms: tuple[str, ...] = TERMS
    #: the STEP it needs: ``"modal"`` (modal coefficients over the retained modes: the targeted STEP
    #: projected on them, or the full plan with ``analysis.tensors = "full"``) or ``"targeted"``
    #: (``G(phi_p, phi_p)`` on the mesh); None: that of its evaluator
    step: str | None = None
    #: solves with the pseudo-inverse ``K^+`` of the supported stiffness
    pinv: bool = False
    #: the shifts ``sigma / w_p^2`` of the systems ``(K - sigma M) x = b`` it solves
    shifts: tuple[float, ...] = ()
    #: defined for a model in modal coordinates (a full-order method as its modal variant over every mode)
    on_modal_model: bool = True

    @property
    def factorises(self) -> bool:
        """Whether it needs the full-order linear algebra (``K^+``, shifted factorisations or deflated
        solves with the eigen-solver's factorisation)."""
        return self.pinv or bool(self.shifts)

    @property
    def shift_above_master(self) -> bool:
        """Whether it solves with a shift above ``w_p^2`` (DNF's ``4 w_p^2``), which the computed
        spectrum may not reach: such a solve may need a factorisation of its own."""
        return any(s > 1.0 for s in self.shifts)

    def resolve(self, qm_order: str) -> "Method":
        """The evaluator of this name: itself, or (``md``, ``smd``) its variant of order ``qm_order``."""
        if self.order is not None:
            return self
        return TABLE[self.modal if qm_order == MODAL else self.full]

    def function(self) -> Callable:
        """The function that computes this evaluator (imported now; module docstring)."""
        if self.evaluator is None:
            raise KeyError(f"method {self.name!r} is computed by its evaluator (Method.resolve)")
        module, _, attr = self.evaluator.rpartition(".")
        return getattr(import_module(module), attr)


_METHODS = (
    Method(NF, "NF", MODAL, NF, DNF, f"{_EVALUATORS}.nf_modal", step="modal"),
    Method(DNF, "DNF", FULL, NF, DNF, f"{_EVALUATORS}.dnf", step="targeted", pinv=True, shifts=(4.0,)),
    Method(MD, "MD", None, MD_MODAL, MD_FULL),
    Method(SMD, "SMD", None, SMD_MODAL, SMD_FULL),
    Method(MD_MODAL, "MD_MODAL", MODAL, MD_MODAL, MD_FULL, f"{_EVALUATORS}.md_modal", step="modal"),
    Method(SMD_MODAL, "SMD_MODAL", MODAL, SMD_MODAL, SMD_FULL, f"{_EVALUATORS}.smd_modal", step="modal"),
    Method(MD_FULL, "MD_FULL", FULL, MD_MODAL, MD_FULL, f"{_EVALUATORS}.md_full", step="targeted", shifts=(1.0,)),
    Method(SMD_FULL, "SMD_FULL", FULL, SMD_MODAL, SMD_FULL, f"{_EVALUATORS}.smd_full", step="targeted", pinv=True),
)
#: name -> :class:`Method`, in the order the scene check lists them
TABLE: dict[str, Method] = {m.name: m for m in _METHODS}
#: every name a scene may write
NAMES: tuple[str, ...] = tuple(TABLE)
#: the evaluators that work on modal coefficients over a retained set of modes
MODAL_EVALUATORS: frozenset[str] = frozenset(m.name for m in _METHODS if m.order == MODAL)
#: the evaluators that work on the whole mesh (shifted solves, no modal truncation)
FULL_EVALUATORS: frozenset[str] = frozenset(m.name for m in _METHODS if m.order == FULL)


def method(name: str) -> Method:
    """The :class:`Method` called ``name`` (a ``KeyError`` naming the known ones otherwise)."""
    try:
        return TABLE[name]
    except KeyError:
        raise KeyError(f"unknown method {name!r}; known: {list(NAMES)}") from None


def evaluators(names: Iterable[str], qm_order: str) -> dict[str, str]:
    """Each of ``names`` mapped to the name of its evaluator: ``md``/``smd`` follow ``qm_order``."""
    return {n: method(n).resolve(qm_order).name for n in names}

"""Fields for ParaView: the mesh with each master mode's shape and second-order displacement fields.

Beside a run's results file ``NAME.h5``, :func:`write_mode_fields` writes
``NAME_fields.xdmf`` (with its heavy data in ``NAME_fields.h5``) and
``NAME_fields.vtu``, both read by ParaView (XDMF: "Xdmf3 Reader"; VTU: the
VTK XML reader) and by meshio. Point data, one 3-component vector per field,
in the model's length unit per unit of modal amplitude (or its square), named
``mode_<p>[_<label>]_<what>``, e.g. ``mode_0_(2,0)_phi``:

``phi``
    the mass-normalised mode shape (``phi^T M phi = 1``).
``dnf_a_bar``, ``dnf_w2_b_bar``
    the direct normal form's a_bar and ``w_p^2 b_bar`` (docs/design.md, Eq. 9-10):
    on the backbone ``x(t) = a cos(wt) phi + a^2 [cos^2(wt) a_bar +
    sin^2(wt) w2_b_bar] + O(a^3)`` (:mod:`stepnf.nf.evaluators`).
``md_theta``, ``smd_theta``
    the modal derivative of the quadratic manifold (MD: dynamic, SMD: static),
    ``x(t) = a cos(wt) phi + (a^2 / 2) cos^2(wt) theta + O(a^3)``; written
    when ``qm_order = "full"`` (modal sums have no vector).

A method that diverged (flagged ``T = +-inf``) has no field. In ParaView,
"Warp By Vector" with ``a^2`` as scale factor shows the in-plane drift that
makes a shell soften.

Placement: the adapter's :meth:`~stepnf.plugin.adapter.SolverAdapter.output_mesh`
gives points and cells; each dof goes to the point nearest its
``dof_coordinates`` (within :data:`MATCH_TOLERANCE` of the mesh size), in its
``dof_directions`` component. Fixed (removed) dofs and points without a dof
stay zero; a dof that lies on no point (a quadratic field on a linear output
mesh) is left out, so such a mesh shows the field at its vertices.

Rotations: the displacement vector of every field holds the translations only
(``ux uy uz``). A model with rotation dofs (a shell's ``rx ry rz``, radians per
unit of modal amplitude or its square) gets one more 3-component vector per
field, the rotation vector, named like the field with :data:`ROTATION_SUFFIX`
(``mode_0_(2,0)_phi_rotation``); a solid's files are unchanged.

Every file is built in a temporary folder beside the target and moved into
place through :func:`stepnf.io.atomic.write_bytes` (the ``.h5`` before the
``.xdmf`` that refers to it); a failure is an :class:`~stepnf.errors.OutputError`
naming the file (exit 3), and never touches the results file.
"""
from __future__ import annotations

import re
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from stepnf.io.atomic import reason, write_bytes
from stepnf.plugin.dofs import FIRST_ROTATION, rotation_mask, translation_mask
from stepnf.plugin.output_mesh import OutputMesh
from stepnf.errors import AdapterError, OutputError

__all__ = ["OutputMesh", "DofPlacement", "dof_placement", "field_name", "collect_fields", "point_fields",
           "write_fields", "write_mode_fields", "FIELD_SUFFIXES", "MATCH_TOLERANCE", "ROTATION_SUFFIX"]

#: Largest distance from a dof's coordinates to its mesh point, relative to the mesh's largest extent.
#: Above the round-off of coordinates that went through a file (7 printed digits: 5e-7), far below
#: the node spacing of any usable mesh (a thin shell's elements are ~1e-3 of its size).
MATCH_TOLERANCE = 1e-6
#: The file suffixes written for a stem (the ``.h5`` first: the ``.xdmf`` refers to it).
FIELD_SUFFIXES = (".h5", ".vtu", ".xdmf")
#: Appended to a field's name for its rotation vector (models with rotation dofs).
ROTATION_SUFFIX = "_rotation"
#: Headroom over the raw size of the fields when checking the free disk space (h5 + vtu in base64).
_SPACE_FACTOR = 3.0


@dataclass(frozen=True)
class DofPlacement:
    """Where each dof goes: its ``point`` (-1: not written) and ``direction`` (0, 1, 2 for x, y, z);
    ``unmatched`` counts the translation dofs that lie on no point of the mesh. ``rotation`` is the same
    placement of the rotation dofs (``rx ry rz`` as components 0, 1, 2), ``None`` without rotation dofs."""

    point: np.ndarray
    direction: np.ndarray
    unmatched: int
    rotation: "DofPlacement | None" = None


def dof_placement(mesh: OutputMesh, coordinates: Any, directions: Any, n_dofs: int,
                  who: str = "solver adapter") -> DofPlacement:
    """The point and component of each of the ``n_dofs`` dofs (see the module docstring).

    ``coordinates`` (n, 3) and ``directions`` (n,) are the adapter's
    ``dof_coordinates()`` and ``dof_directions()``; ``who`` names the adapter in
    the :class:`~stepnf.errors.AdapterError` raised when they are missing, of the
    wrong length, or when no dof lies on a point of the mesh.
    """
    from scipy.spatial import cKDTree

    if coordinates is None or directions is None:
        raise AdapterError(f"{who}: output_mesh() needs dof_coordinates() and dof_directions(), and one is None")
    X = np.asarray(coordinates, dtype=float)
    D = np.asarray(directions).astype(np.int64)
    P = np.asarray(mesh.points, dtype=float)
    if X.shape != (n_dofs, 3) or D.shape != (n_dofs,):
        raise AdapterError(f"{who}: dof_coordinates() has shape {X.shape} and dof_directions() {D.shape}; expected "
                           f"({n_dofs}, 3) and ({n_dofs},) for its {n_dofs} dofs")
    if P.ndim != 2 or P.shape[1] != 3 or len(P) == 0:
        raise AdapterError(f"{who}: output_mesh() has points of shape {P.shape}; expected (P, 3), P > 0")
    scale = float(np.ptp(P, axis=0).max()) or 1.0
    dist, idx = cKDTree(P).query(X)
    translation = translation_mask(D)
    on_point = dist <= MATCH_TOLERANCE * scale
    if translation.any() and not (on_point & translation).any():
        raise AdapterError(f"{who}: none of its dofs lies on a point of its output mesh (nearest at "
                           f"{float(dist.min()):.3g}, mesh size {scale:.3g}): output_mesh() and dof_coordinates() "
                           "disagree")
    keep = on_point & translation
    point = np.where(keep, idx, -1).astype(np.int64)
    rotation = rotation_mask(D)
    rot = None
    if rotation is not None:
        on = on_point & rotation
        rot = DofPlacement(np.where(on, idx, -1).astype(np.int64), np.where(on, D - FIRST_ROTATION, 0),
                           int(np.count_nonzero(rotation & ~on_point)))
    return DofPlacement(point, np.where(keep, D, 0), int(np.count_nonzero(translation & ~on_point)), rot)


def point_fields(fields: Mapping[str, np.ndarray], placement: DofPlacement, n_points: int) -> dict[str, np.ndarray]:
    """Each dof vector (n,) of ``fields`` as point data (n_points, 3): zeros where no dof is placed."""
    sel = placement.point >= 0
    out = {}
    for name, v in fields.items():
        a = np.zeros((n_points, 3))
        a[placement.point[sel], placement.direction[sel]] = np.asarray(v, dtype=float)[sel]
        out[name] = a
    return out


_UNSAFE = re.compile(r"[^A-Za-z0-9_(),.+-]")


def field_name(index: int, label: Any, what: str) -> str:
    """``mode_<index>[_<label>]_<what>``: a ``(k, n)`` label is written ``(k,n)``; other characters than
    letters, digits and ``_(),.+-`` become ``_`` (names valid in XDMF, VTU and ParaView's calculator)."""
    if label is None:
        text = ""
    elif isinstance(label, (tuple, list)):
        text = "(" + ",".join(str(x) for x in label) + ")"
    else:
        text = str(label)
    prefix = f"mode_{int(index)}" + (f"_{_UNSAFE.sub('_', text)}" if text else "")
    return f"{prefix}_{_UNSAFE.sub('_', what)}"


def collect_fields(modes: Sequence[Any], phi_masters: np.ndarray) -> dict[str, np.ndarray]:
    """The dof vectors to write, by field name: per master mode (a :class:`stepnf.io.results.ModeResult`,
    in the order of the columns of ``phi_masters`` (n, len(modes))), its shape ``phi`` and the
    ``fields`` of each of its methods (``md_full`` written as ``md``; the first of two that coincide wins)."""
    Phi = np.asarray(phi_masters, dtype=float)
    if Phi.ndim != 2 or Phi.shape[1] != len(modes):
        raise ValueError(f"phi_masters has shape {Phi.shape}; expected (n, {len(modes)}), one column per master mode")
    out: dict[str, np.ndarray] = {}
    for j, rec in enumerate(modes):
        out[field_name(rec.index, rec.label, "phi")] = Phi[:, j]
        for name, r in rec.methods.items():
            meth = name[:-5] if name.endswith("_full") else name
            for key, vec in getattr(r, "fields", {}).items():
                out.setdefault(field_name(rec.index, rec.label, f"{meth}_{key}"), vec)
    return out


def _targets(stem: Path) -> list[Path]:
    return [stem.parent / (stem.name + s) for s in FIELD_SUFFIXES]


def write_fields(path_stem: str | Path, mesh: OutputMesh, fields: Mapping[str, np.ndarray]) -> list[Path]:
    """Write ``mesh`` with the point data ``fields`` (name -> (P, 3)) to ``<stem>.xdmf`` (+ ``<stem>.h5``)
    and ``<stem>.vtu``; return the paths written (``.h5``, ``.vtu``, ``.xdmf``).

    Raises :class:`~stepnf.errors.OutputError` naming the file that could not be
    written (full disk, read-only folder, ...). Each file is replaced atomically,
    so a failure leaves every file whole: its previous version or the new one (a
    failure while building the files, meshio's part, leaves all three untouched).
    """
    import meshio

    stem = Path(path_stem)
    h5, vtu, xdmf = targets = _targets(stem)
    P = int(mesh.n_points)
    for name, a in fields.items():
        if np.shape(a) != (P, 3):
            raise ValueError(f"field {name!r} has shape {np.shape(a)}; expected ({P}, 3)")
    try:
        m = meshio.Mesh(np.asarray(mesh.points, dtype=float), [(t, np.asarray(c)) for t, c in mesh.cells],
                        point_data={k: np.asarray(v, dtype=float) for k, v in fields.items()})
    except Exception as exc:  # noqa: BLE001 - an unknown cell type is a KeyError, ragged cells a ValueError
        raise OutputError(f"cannot write the field file {xdmf}: meshio failed: the output mesh is not one "
                          f"meshio can write ({type(exc).__name__}: {exc})", path=xdmf) from exc
    raw = 8 * 3 * P * (1 + len(fields)) + sum(np.asarray(c).nbytes for _, c in mesh.cells)
    folder = stem.parent
    try:
        folder.mkdir(parents=True, exist_ok=True)
        free = shutil.disk_usage(folder).free
        if free < _SPACE_FACTOR * raw:  # h5py may crash on a full disk: do not start
            raise OutputError(f"cannot write the field file {h5}: no space left on device (ENOSPC): about "
                              f"{_SPACE_FACTOR * raw / 1e6:.1f} MB needed, {free / 1e6:.1f} MB free", path=h5)
        tmp = Path(tempfile.mkdtemp(prefix=f".{stem.name}.", suffix=".tmp", dir=folder))
    except OSError as exc:
        raise OutputError(f"cannot write the field file {xdmf}: {reason(exc)}", path=xdmf,
                          errno=exc.errno) from exc
    try:
        current = xdmf
        try:
            meshio.xdmf.write(tmp / xdmf.name, m, data_format="HDF")
            current = vtu
            meshio.vtu.write(tmp / vtu.name, m, binary=True)
        except OSError as exc:
            raise OutputError(f"cannot write the field file {current}: {reason(exc)}", path=current,
                              errno=exc.errno) from exc
        except Exception as exc:  # noqa: BLE001 - meshio raises many kinds (unknown cell type, ...)
            raise OutputError(f"cannot write the field file {current}: meshio failed: {exc}", path=current) from exc
        for target in targets:
            try:
                data = (tmp / target.name).read_bytes()
            except OSError as exc:
                raise OutputError(f"cannot write the field file {target}: {reason(exc)}", path=target,
                                  errno=exc.errno) from exc
            write_bytes(target, data, what="field file")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return targets


def write_mode_fields(results_path: str | Path, mesh: OutputMesh, modes: Sequence[Any], phi_masters: np.ndarray,
                      coordinates: Any, directions: Any, *, who: str = "solver adapter") -> list[Path]:
    """Write the fields of a run beside its results file ``results_path`` (``NAME.h5``): ``NAME_fields.xdmf``,
    ``NAME_fields.h5``, ``NAME_fields.vtu``; return their paths.

    ``mesh`` is the adapter's ``output_mesh()``; ``modes`` the run's
    :class:`stepnf.io.results.ModeResult` s (their methods' ``fields``, see
    :mod:`stepnf.nf.evaluators`); ``phi_masters`` (n, len(modes)) their
    mass-normalised mode shapes; ``coordinates``, ``directions`` the adapter's
    ``dof_coordinates()`` and ``dof_directions()``; ``who`` names the adapter in
    messages. Raises :class:`~stepnf.errors.OutputError` naming the file not
    written, also when the mesh and the dofs do not fit (the adapter's fault,
    said in the message), so that a caller handles every failure here alike.
    """
    results_path = Path(results_path)
    stem = results_path.parent / f"{results_path.stem}_fields"
    Phi = np.asarray(phi_masters, dtype=float)
    try:
        placement = dof_placement(mesh, coordinates, directions, Phi.shape[0], who)
    except AdapterError as exc:
        xdmf = _targets(stem)[-1]
        raise OutputError(f"cannot write the field file {xdmf}: {exc}", path=xdmf) from exc
    dofs = collect_fields(modes, Phi)
    points = point_fields(dofs, placement, mesh.n_points)
    if placement.rotation is not None:
        turns = point_fields(dofs, placement.rotation, mesh.n_points)
        points.update({name + ROTATION_SUFFIX: turns[name] for name in dofs})
    return write_fields(stem, mesh, points)

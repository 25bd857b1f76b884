"""Reading and writing MED files (HDF5) with h5py: nodal result fields and simple volume meshes.

Layout (MED 3.x) used here:

* ``/CHA/<field>``: attributes ``MAI`` (mesh name), ``NCO`` (number of
  components), ``NOM`` (component names in 16-character slots), ``TYP``
  (6 = float64);
* ``/CHA/<field>/<step>``: one group per time step, named by two 20-digit
  numbers (``NDT`` then ``NOR``), attributes ``NDT``, ``NOR``, ``PDT`` (the
  time; for code_aster modal results the frequency);
* ``.../<step>/NOE/<profile>/CO``: nodal values, stored component by component
  (reshape to ``(NBR, NCO)`` in Fortran order); ``<profile>`` is
  ``MED_NO_PROFILE_INTERNAL`` (every node) or the name of a profile whose
  1-based node numbers are ``/PROFILS/<profile>/PFL``;
* ``/ENS_MAA/<mesh>/<step>/NOE/COO``: node coordinates, Fortran order
  ``(NBR, DIM)``; ``.../MAI/<type>/NOD``: connectivity (1-based, Fortran order).

MED orders the nodes of a hexahedron like VTK but with the opposite
orientation (its first face is VTK's last): :data:`MED_FROM_VTK` maps one to
the other (the permutation is its own inverse).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from stepnf.errors import SolverRunError

NO_PROFILE = "MED_NO_PROFILE_INTERNAL"
#: MED geometry codes and names of the cells written here.
MED_CELLS = {"hexahedron20": ("H20", 320), "hexahedron": ("HE8", 308), "hexahedron27": ("H27", 327),
             # shells' mid-surfaces (code_aster DKT, COQUE_3D): same node order as VTK's (quad9, triangle7:
             # corners, mid-sides, centre)
             "triangle": ("TR3", 203), "quad": ("QU4", 204), "triangle7": ("TR7", 207), "quad9": ("QU9", 209)}
#: Column k of a MED H20 connectivity is column MED_FROM_VTK[k] of a VTK hexahedron20 one.
MED_FROM_VTK = {
    "hexahedron": np.array([4, 5, 6, 7, 0, 1, 2, 3]),
    "hexahedron20": np.array([4, 5, 6, 7, 0, 1, 2, 3, 12, 13, 14, 15, 8, 9, 10, 11, 16, 17, 18, 19]),
}


class MedError(SolverRunError, ValueError):
    """A MED file does not hold what was asked for.

    A solver failure (:class:`stepnf.errors.SolverRunError`, exit code 3 of the
    CLI) and still a :class:`ValueError`, as before it joined stepnf's errors:
    the adapter turns an unreadable user's mesh into a
    :class:`stepnf.errors.SceneError` by catching ``ValueError``.
    """


@dataclass
class NodalStep:
    """Values of a nodal field at one time step.

    ``values`` (NBR, NCO); ``nodes`` 0-based node indices of the rows (all
    nodes when the field has no profile); ``time`` the step's ``PDT``.
    """

    field: str
    components: list[str]
    ndt: int
    nor: int
    time: float
    nodes: np.ndarray
    values: np.ndarray

    def full(self, n_nodes: int, fill: float = 0.0) -> np.ndarray:
        """Values (n_nodes, NCO) on every node, ``fill`` where the profile has none."""
        out = np.full((n_nodes, self.values.shape[1]), fill)
        out[self.nodes] = self.values
        return out

    def component(self, name: str) -> np.ndarray:
        """One component by name (e.g. ``"DZ"``)."""
        try:
            return self.values[:, self.components.index(name)]
        except ValueError:
            raise MedError(f"field {self.field!r} has no component {name!r}. Pick one of {self.components}") from None


def _names(attr, width: int = 16) -> list[str]:
    s = attr.decode() if isinstance(attr, bytes) else str(attr)
    return [s[i:i + width].strip() for i in range(0, len(s), width) if s[i:i + width].strip()]


def _text(attr) -> str:
    return (attr.decode() if isinstance(attr, bytes) else str(attr)).strip()


def list_fields(path: str | Path) -> dict[str, list[str]]:
    """Field names of a MED file with their component names."""
    import h5py

    with h5py.File(path, "r") as f:
        if "CHA" not in f:
            return {}
        return {name: _names(g.attrs["NOM"]) for name, g in f["CHA"].items()}


def read_nodal_steps(path: str | Path, field: str) -> list[NodalStep]:
    """Every time step of the nodal field ``field``, in file order (increasing NDT, NOR)."""
    import h5py

    path = Path(path)
    if not path.is_file():
        raise MedError(f"MED file {path} does not exist")
    with h5py.File(path, "r") as f:
        if "CHA" not in f or field not in f["CHA"]:
            have = list(f["CHA"]) if "CHA" in f else []
            raise MedError(f"{path}: no field {field!r}. Pick one of {have}")
        g = f["CHA"][field]
        comps = _names(g.attrs["NOM"])
        nco = int(g.attrs["NCO"])
        out = []
        for key in sorted(g):
            st = g[key]
            if "NOE" not in st:
                raise MedError(f"{path}: field {field!r} step {key} is not a nodal field (entities {list(st)})")
            noe = st["NOE"]
            pfl = _text(noe.attrs.get("PFL", NO_PROFILE)) or NO_PROFILE
            if pfl not in noe:  # some writers name the data group differently: take the only one
                if len(noe) != 1:
                    raise MedError(f"{path}: field {field!r} step {key}: profile {pfl!r} not found")
                pfl = next(iter(noe))
            data = noe[pfl]
            nbr = int(data.attrs["NBR"])
            nga = int(data.attrs.get("NGA", 1))
            co = np.asarray(data["CO"], dtype=float)
            if co.size != nbr * nco * nga:
                raise MedError(f"{path}: field {field!r} step {key}: {co.size} values, expected {nbr} x {nco}")
            values = co.reshape((nbr, nco), order="F")
            if pfl == NO_PROFILE:
                nodes = np.arange(nbr)
            else:
                if "PROFILS" not in f or pfl not in f["PROFILS"]:
                    raise MedError(f"{path}: profile {pfl!r} of field {field!r} is not under /PROFILS")
                nodes = np.asarray(f["PROFILS"][pfl]["PFL"], dtype=np.int64) - 1
            out.append(NodalStep(field, comps, int(st.attrs["NDT"]), int(st.attrs["NOR"]),
                                 float(st.attrs["PDT"]), nodes, values))
        return out


def read_nodal_field(path: str | Path, field: str, step: int = 0) -> NodalStep:
    """One step (index into :func:`read_nodal_steps`) of a nodal field."""
    steps = read_nodal_steps(path, field)
    if not -len(steps) <= step < len(steps):
        raise MedError(f"{path}: field {field!r} has {len(steps)} step(s), asked for step {step}")
    return steps[step]


def read_profile(path: str | Path, name: str) -> np.ndarray:
    """0-based node indices of the profile ``name``."""
    import h5py

    with h5py.File(path, "r") as f:
        if "PROFILS" not in f or name not in f["PROFILS"]:
            raise MedError(f"{path}: no profile {name!r}")
        return np.asarray(f["PROFILS"][name]["PFL"], dtype=np.int64) - 1


def read_mesh_nodes(path: str | Path, mesh: str | None = None) -> np.ndarray:
    """Node coordinates (N, DIM) of ``mesh`` (the first mesh when ``None``).

    Raises :class:`MedError` for a file that is not HDF5/MED, a mesh without
    nodes, or a node with NaN or inf coordinates (naming the node, 0-based).
    """
    import h5py

    try:
        with h5py.File(path, "r") as f:
            X = read_mesh_nodes_h5(f, mesh)
    except MedError:
        raise
    except (OSError, KeyError, ValueError, StopIteration) as exc:
        raise MedError(f"{path}: not a readable MED mesh ({type(exc).__name__}: {exc})") from None
    if X.size == 0:
        raise MedError(f"{path}: the mesh has no nodes")
    bad = ~np.isfinite(X).all(axis=1)
    if bad.any():
        i = int(np.nonzero(bad)[0][0])
        raise MedError(f"{path}: node {i} has coordinates {X[i].tolist()} (NaN or inf); {int(bad.sum())} node(s) do")
    return X


def mesh_name(path: str | Path) -> str:
    """Name of the first mesh of a MED file; :class:`MedError` when there is none or the file is unreadable."""
    import h5py

    try:
        with h5py.File(path, "r") as f:
            return next(iter(f["ENS_MAA"]))
    except (OSError, KeyError, ValueError, StopIteration) as exc:
        raise MedError(f"{path}: not a readable MED mesh ({type(exc).__name__}: {exc})") from None


# --------------------------------------------------------------------- writer
def _s(text: str) -> np.bytes_:
    return np.bytes_(text.encode())


def _names16(names: Sequence[str]) -> np.bytes_:
    return _s("".join(f"{n:<16}"[:16] for n in names))


def _step_name(ndt: int, nor: int) -> str:
    return f"{ndt:020d}{nor:020d}"


def write_med(path: str | Path, points: np.ndarray, cells: np.ndarray, cell_type: str = "hexahedron20",
              *, mesh_name: str = "mesh", fields: dict[str, tuple[Sequence[str], Sequence[tuple[float, np.ndarray]]]]
              | None = None) -> Path:
    """Write a one-cell-type volume mesh and nodal float fields to a MED 3.2 file.

    ``cells`` are 0-based in VTK order (converted to MED's orientation);
    ``fields`` maps a field name to ``(component names, [(time, values (N, NCO)), ...])``;
    step ``i`` gets ``NDT = NOR = i`` (as code_aster writes its results) and ``PDT = time``.
    """
    import h5py

    if cell_type not in MED_CELLS:
        raise MedError(f"cell type {cell_type!r} cannot be written. Pick one of {list(MED_CELLS)}")
    med_name, geo = MED_CELLS[cell_type]
    cells = np.asarray(cells, dtype=np.int64)
    if cell_type in MED_FROM_VTK:
        cells = cells[:, MED_FROM_VTK[cell_type]]
    points = np.asarray(points, dtype=float)
    n, dim = points.shape
    i32 = np.int32
    with h5py.File(path, "w") as f:
        info = f.create_group("INFOS_GENERALES")
        for k, v in (("MAJ", 3), ("MIN", 2), ("REL", 0)):
            info.attrs.create(k, v, dtype=i32)
        m = f.create_group("ENS_MAA").create_group(mesh_name)
        for k, v in (("DIM", dim), ("ESP", dim), ("NXI", -1), ("NXT", -1), ("REP", 0), ("SRT", 1), ("TYP", 0)):
            m.attrs.create(k, v, dtype=i32)
        m.attrs["DES"] = _s("written by stepnf")
        m.attrs["NOM"] = _names16("XYZ"[:dim])
        m.attrs["UNI"] = _names16([""] * dim)
        m.attrs["UNT"] = _s("")
        st = m.create_group(_step_name(-1, -1))
        for k, v in (("CGT", 1), ("NDT", -1), ("NOR", -1), ("NXI", -1), ("NXT", -1), ("PVI", -1), ("PVT", -1)):
            st.attrs.create(k, v, dtype=i32)
        st.attrs.create("PDT", -1.0)
        noe = st.create_group("NOE")
        for k, v in (("CGS", 1), ("CGT", 1)):
            noe.attrs.create(k, v, dtype=i32)
        noe.attrs["PFL"] = _s(NO_PROFILE)
        d = noe.create_dataset("COO", data=points.ravel(order="F"))
        d.attrs.create("CGT", 1, dtype=i32)
        d.attrs.create("NBR", n, dtype=i32)
        d = noe.create_dataset("FAM", data=np.zeros(n, dtype=i32))
        d.attrs.create("CGT", 1, dtype=i32)
        d.attrs.create("NBR", n, dtype=i32)
        mai = st.create_group("MAI")
        mai.attrs.create("CGT", 1, dtype=i32)
        c = mai.create_group(med_name)
        for k, v in (("CGS", 1), ("CGT", 1), ("GEO", geo)):
            c.attrs.create(k, v, dtype=i32)
        c.attrs["PFL"] = _s(NO_PROFILE)
        d = c.create_dataset("NOD", data=(cells + 1).ravel(order="F").astype(i32))
        d.attrs.create("CGT", 1, dtype=i32)
        d.attrs.create("NBR", len(cells), dtype=i32)
        d = c.create_dataset("FAM", data=np.zeros(len(cells), dtype=i32))
        d.attrs.create("CGT", 1, dtype=i32)
        d.attrs.create("NBR", len(cells), dtype=i32)
        fas = f.create_group("FAS").create_group(mesh_name)
        fas.create_group("FAMILLE_ZERO").attrs.create("NUM", 0, dtype=i32)
        f.create_group("CHA")
    for name, (comps, steps) in (fields or {}).items():
        add_nodal_field(path, name, comps, steps, mesh_name=mesh_name)
    return Path(path)


def add_nodal_field(path: str | Path, name: str, components: Sequence[str],
                    steps: Sequence[tuple[float, np.ndarray]], *, mesh_name: str = "mesh") -> None:
    """Append a nodal float field (every node, no profile) to an existing MED file.

    ``steps``: ``[(time, values (N, NCO)), ...]``; step ``i`` gets
    ``NDT = NOR = i`` (as code_aster writes its results) and ``PDT = time``.
    """
    import h5py

    i32 = np.int32
    with h5py.File(path, "a") as f:
        n = len(read_mesh_nodes_h5(f, mesh_name))
        cha = f.require_group("CHA")
        if name in cha:
            raise MedError(f"{path}: field {name!r} already exists")
        g = cha.create_group(name)
        g.attrs["MAI"] = _s(mesh_name)
        g.attrs.create("NCO", len(components), dtype=i32)
        g.attrs["NOM"] = _names16(components)
        g.attrs.create("TYP", 6, dtype=i32)
        g.attrs["UNI"] = _names16([""] * len(components))
        g.attrs["UNT"] = _s("")
        for i, (time, values) in enumerate(steps):
            values = np.asarray(values, dtype=float).reshape(n, len(components))
            s = g.create_group(_step_name(i, i))
            for k, v in (("NDT", i), ("NOR", i), ("RDT", -1), ("ROR", -1)):
                s.attrs.create(k, v, dtype=i32)
            s.attrs.create("PDT", float(time))
            e = s.create_group("NOE")
            e.attrs["GAU"] = _s("")
            e.attrs["PFL"] = _s(NO_PROFILE)
            p = e.create_group(NO_PROFILE)
            p.attrs["GAU"] = _s("")
            p.attrs.create("NBR", n, dtype=i32)
            p.attrs.create("NGA", 1, dtype=i32)
            p.create_dataset("CO", data=values.ravel(order="F"))


def read_mesh_nodes_h5(f, mesh: str | None = None) -> np.ndarray:
    """Node coordinates (N, DIM) of ``mesh`` in an open h5py file."""
    meshes = f["ENS_MAA"]
    name = mesh or next(iter(meshes))
    if name not in meshes:
        raise MedError(f"{f.filename}: no mesh {name!r}. Pick one of {list(meshes)}")
    st = next(iter(meshes[name].values()))
    coo = st["NOE"]["COO"]
    n = int(coo.attrs["NBR"])
    return np.asarray(coo, dtype=float).reshape((n, -1), order="F")


def read_groups(path: str | Path, mesh: str | None = None) -> dict[str, np.ndarray]:
    """The mesh's named groups as node sets ``{name: 0-based node indices}`` (for ``[[model.boundary]]``).

    A MED group is a name carried by families: a node family (``NUM > 0``) holds the nodes whose
    ``NOE/FAM`` is its number, a cell family (``NUM < 0``) the cells whose ``MAI/<type>/FAM`` is; a
    group of cells names the nodes of those cells (a face group names the nodes of its faces).
    """
    import h5py

    try:
        with h5py.File(path, "r") as f:
            name = mesh or next(iter(f["ENS_MAA"]))
            families = _family_groups(f, name)
            st = next(iter(f["ENS_MAA"][name].values()))
            found: dict[str, list[np.ndarray]] = {}
            fam = np.asarray(st["NOE"]["FAM"]) if "FAM" in st["NOE"] else np.zeros(0, dtype=int)
            for num, groups in families.items():
                if num > 0:
                    for g in groups:
                        found.setdefault(g, []).append(np.flatnonzero(fam == num))
            for block in (st["MAI"].values() if "MAI" in st else ()):
                if "FAM" not in block or "NOD" not in block:
                    continue
                cfam = np.asarray(block["FAM"])
                conn = np.asarray(block["NOD"]).reshape((len(cfam), -1), order="F") - 1
                for num, groups in families.items():
                    if num < 0 and np.any(cfam == num):
                        for g in groups:
                            found.setdefault(g, []).append(conn[cfam == num].ravel())
    except (OSError, KeyError, ValueError, StopIteration) as exc:
        raise MedError(f"{path}: cannot read the groups of the MED mesh ({type(exc).__name__}: {exc})") from None
    return {g: np.unique(np.concatenate(parts)) for g, parts in found.items()}


def _family_groups(f, mesh: str) -> dict[int, list[str]]:
    """Family number -> group names, from ``FAS/<mesh>`` (80-byte names)."""
    out: dict[int, list[str]] = {}
    fas = f["FAS"][mesh] if "FAS" in f and mesh in f["FAS"] else {}
    for kind in ("NOEUD", "ELEME"):
        for fam in (fas[kind].values() if kind in fas else ()):
            if "GRO" not in fam:
                continue
            names = np.asarray(fam["GRO"]["NOM"][()]).reshape(-1, 80).astype(np.uint8)
            out[int(fam.attrs["NUM"])] = [bytes(row).decode("ascii", "replace").strip() for row in names]
    return out


#: MED names of the volume cells (the cells that carry a material; faces and edges do not).
MED_VOLUME_CELLS = ("TE4", "T10", "PY5", "P13", "PE6", "P15", "P18", "HE8", "H20", "H27")


def read_cell_groups(path: str | Path, mesh: str | None = None) -> tuple[int, dict[str, np.ndarray]]:
    """The volume cells of the mesh and its groups of them: ``(n_cells, {name: 0-based cell positions})``
    (for ``[model.materials.<set>]``).

    Cells are numbered block by block in the order of :data:`MED_VOLUME_CELLS`, each block in
    its file order; a cell family (``NUM < 0``) names the cells whose ``MAI/<type>/FAM`` is its
    number. A group of faces only is listed with no cell (``assign_cells`` refuses it).
    """
    import h5py

    try:
        with h5py.File(path, "r") as f:
            name = mesh or next(iter(f["ENS_MAA"]))
            families = {num: groups for num, groups in _family_groups(f, name).items() if num < 0}
            st = next(iter(f["ENS_MAA"][name].values()))
            mai = st["MAI"] if "MAI" in st else {}
            found: dict[str, list[np.ndarray]] = {g: [] for groups in families.values() for g in groups}
            start = 0
            for kind in MED_VOLUME_CELLS:
                if kind not in mai or "NOD" not in mai[kind]:
                    continue
                n = int(mai[kind]["NOD"].attrs["NBR"])
                cfam = np.asarray(mai[kind]["FAM"]) if "FAM" in mai[kind] else np.zeros(n, dtype=int)
                for num, groups in families.items():
                    for g in groups:
                        found[g].append(start + np.flatnonzero(cfam == num))
                start += n
    except (OSError, KeyError, ValueError, StopIteration) as exc:
        raise MedError(f"{path}: cannot read the cell groups of the MED mesh ({type(exc).__name__}: {exc})") from None
    empty = np.zeros(0, dtype=np.int64)
    return start, {g: np.unique(np.concatenate(parts)) if parts else empty for g, parts in found.items()}

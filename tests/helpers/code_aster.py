"""The code_aster adapter's test fixtures: a fake ``run_aster``, a small generated cap, MED files with cell groups.

code_aster itself is not needed: :data:`FAKE_RUN_ASTER` is a Python script that reads the .export and the MED
input and writes the outputs code_aster would write (f(u) = K u + u**3 with a known K).
"""
from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np

ISO = {"E": 1.04e11, "nu": 0.3, "rho": 4400.0}
CAP = {"shape": "spherical_cap", "a": 0.15, "R": 1.5, "h": 0.003, "n_core": 2, "n_ring": 1}
ORTHO = {"E1": 1.3e11, "E2": 9.1e9, "E3": 9.2e9, "nu12": 0.31, "nu13": 0.29, "nu23": 0.45, "G12": 5.1e9,
         "G13": 5.2e9, "G23": 3.1e9, "rho": 1600.5}
AXES = [[1.0, 2.0, 0.5], [-0.3, 1.0, 2.0]]

FAKE_RUN_ASTER = textwrap.dedent(
    """\
    #!{python}
    # Fake run_aster: does what the templates ask code_aster to do, for f(u) = K u + u**3 with a known K.
    import re, sys
    from pathlib import Path
    import numpy as np
    from stepnf_code_aster.med import read_mesh_nodes, read_nodal_steps, write_med
    export = Path(sys.argv[1])
    files = {{}}
    for line in export.read_text().splitlines():
        if line.startswith("F "):
            _, kind, path, _, unit = line.split()
            files[kind] = Path(path)
    comm = files["comm"].read_text()
    print("fake run_aster:", files["comm"].name, flush=True)
    if "FAIL" in comm:
        print("<F> <MED2_4> le champ est absent du fichier MED", flush=True)
        sys.exit(4)
    X = read_mesh_nodes(files["mmed"])
    n = 3 * len(X)
    K = 2.0 * np.eye(n) - np.eye(n, k=1) - np.eye(n, k=-1)
    perm = np.random.default_rng(5).permutation(n)  # code_aster's own equation numbering
    if "ASSEMBLAGE" in comm:
        target = re.search(r'np.savez\\(\\s*"([^"]+)"', comm).group(1)
        Kp = K[np.ix_(perm, perm)]
        r, c = np.nonzero(np.tril(Kp))  # one triangle, as EXTR_MATR gives symmetric matrices
        np.savez(target, K_values=Kp[r, c], K_rows=r, K_cols=c, M_values=np.ones(n), M_rows=np.arange(n),
                 M_cols=np.arange(n), n=n, dof_nodes=perm // 3,
                 dof_components=np.array(["DX", "DY", "DZ"])[perm % 3])
    else:
        steps = read_nodal_steps(files["mmed"], "U")
        out = []
        for s in steps:
            u = s.values.ravel()
            if "DROP_LAST" in comm and s is steps[-1]:
                continue
            out.append((s.time, (K @ u + u**3).reshape(-1, 3)))
        cells = np.zeros((0, 20), int)
        write_med(files["rmed"], X, cells, fields={{"F": (["DX", "DY", "DZ"], out)}})
    print("fake run_aster: done", flush=True)
    """
)


def cap(tmp_path, **kw):
    """The code_aster adapter on the generated CAP of ISO (plus ``kw`` model keys), programs allowed."""
    from stepnf.runtime.programs import allow_programs
    from stepnf_code_aster import CodeAsterAdapter

    with allow_programs():  # command and templates name programs: the user allows them here
        return CodeAsterAdapter.from_config({"geometry": CAP, "material": ISO, **kw}, base_dir=tmp_path)


def grouped_med(tmp_path, groups: dict[str, slice], name="part.med") -> Path:
    """The CAP's hex20 mesh as a MED file whose cells carry the named groups (one family per group)."""
    import h5py
    from stepnf_code_aster import write_med

    ad = cap(tmp_path)
    path = tmp_path / name
    write_med(path, ad.points, ad.cells, "hexahedron20")
    member = np.zeros((len(ad.cells), len(groups)), dtype=bool)
    for k, cells in enumerate(groups.values()):
        member[cells, k] = True
    names = list(groups)
    with h5py.File(path, "r+") as f:
        st = next(iter(f["ENS_MAA"]["mesh"].values()))
        fam = np.zeros(len(ad.cells), dtype=np.int32)
        eleme = f["FAS"]["mesh"].create_group("ELEME")
        for num, row in enumerate(np.unique(member[member.any(axis=1)], axis=0), 1):  # one family per combination
            fam[(member == row).all(axis=1)] = -num
            held = [names[k] for k in np.flatnonzero(row)]
            g = eleme.create_group(f"FAM_-{num}")
            g.attrs.create("NUM", -num, dtype=np.int32)
            nom = np.frombuffer("".join(h.ljust(80) for h in held).encode(), np.int8).reshape(len(held), 80)
            g.create_group("GRO").create_dataset("NOM", data=nom)
        st["MAI"]["H20"]["FAM"][...] = fam
    return path


def from_mesh(tmp_path, path, **kw):
    """The code_aster adapter on the mesh file ``path`` in ``tmp_path`` (plus ``kw`` model keys), programs allowed."""
    from stepnf_code_aster import CodeAsterAdapter

    cfg = {"mesh": path.name, **kw}
    from stepnf.runtime.programs import allow_programs

    with allow_programs():  # command and templates name programs: the user allows them here
        return CodeAsterAdapter.from_config(cfg, base_dir=tmp_path, scene_file=tmp_path / "scene.toml")

"""The code_aster adapter's test fixtures: a fake ``run_aster``, a small generated cap, MED files with cell groups.

code_aster itself is not needed: :data:`FAKE_RUN_ASTER` is a Python script that reads the .export and the MED
input and writes the outputs code_aster would write (f(u) = K u + u**3 with a known K; for a DKT shell's command
files over the six dofs DX DY DZ DRX DRY DRZ of every node).
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
    comps = ["DX", "DY", "DZ", "DRX", "DRY", "DRZ"] if 'MODELISATION="DKT"' in comm else ["DX", "DY", "DZ"]
    k = len(comps)  # a DKT shell's nodes carry rotations too
    n = k * len(X)
    K = 2.0 * np.eye(n) - np.eye(n, k=1) - np.eye(n, k=-1)
    perm = np.random.default_rng(5).permutation(n)  # code_aster's own equation numbering
    if "ASSEMBLAGE" in comm:
        target = re.search(r'np.savez\\(\\s*"([^"]+)"', comm).group(1)
        Kp = K[np.ix_(perm, perm)]
        r, c = np.nonzero(np.tril(Kp))  # one triangle, as EXTR_MATR gives symmetric matrices
        np.savez(target, K_values=Kp[r, c], K_rows=r, K_cols=c, M_values=np.ones(n), M_rows=np.arange(n),
                 M_cols=np.arange(n), n=n, dof_nodes=perm // k,
                 dof_components=np.array(comps)[perm % k])
    else:
        steps = read_nodal_steps(files["mmed"], "U")
        out = []
        for s in steps:
            u = s.values.ravel()
            if "DROP_LAST" in comm and s is steps[-1]:
                continue
            out.append((s.time, (K @ u + u**3).reshape(-1, k)))
        cells = np.zeros((0, 20), int)
        write_med(files["rmed"], X, cells, fields={{"F": (comps, out)}})
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


def shell_plate_med(tmp_path, cell_type="quad", n=3, L=0.2, name=None) -> Path:
    """A flat L x L mid-surface mesh in z = 0 of n x n ``quad`` (QU4), ``triangle`` (TR3, two a square) or
    ``quad9`` (QU9: corners, mid-sides, centre) cells, as a MED file (code_aster's DKT or COQUE_3D meshes)."""
    from stepnf_code_aster import write_med

    m = 2 * n if cell_type == "quad9" else n
    xs = np.linspace(0.0, L, m + 1)
    X = np.array([(x, y, 0.0) for y in xs for x in xs])
    k = lambda i, j: j * (m + 1) + i  # noqa: E731
    if cell_type == "quad9":
        cells = [(k(i, j), k(i + 2, j), k(i + 2, j + 2), k(i, j + 2), k(i + 1, j), k(i + 2, j + 1), k(i + 1, j + 2),
                  k(i, j + 1), k(i + 1, j + 1)) for j in range(0, m, 2) for i in range(0, m, 2)]
    elif cell_type == "triangle":
        cells = [c for j in range(n) for i in range(n)
                 for c in ((k(i, j), k(i + 1, j), k(i + 1, j + 1)), (k(i, j), k(i + 1, j + 1), k(i, j + 1)))]
    else:
        cells = [(k(i, j), k(i + 1, j), k(i + 1, j + 1), k(i, j + 1)) for j in range(n) for i in range(n)]
    path = tmp_path / (name or f"plate_{cell_type}.med")
    write_med(path, X, np.array(cells), cell_type)
    return path


def catalogue_adapters(tmp_path, route: str) -> dict:
    """One adapter per kind of rendered command file (materials, groups, axes, boundary conditions; with route
    ``"stat_non_line"`` also the DKT and COQUE_3D shells): the variants held to code_aster's catalogue."""
    n = len(cap(tmp_path).cells)
    groups = grouped_med(tmp_path, {"CORE": slice(0, n // 2), "SKIN": slice(n // 2, n - 1)}, "groups.med")
    plain = grouped_med(tmp_path, {}, "plain.med")
    r = {"force_route": route}
    skin = {"E": 7.1e10, "nu": 0.33, "rho": 2700.0}
    out = {
        "isotropic cap": cap(tmp_path, **r),
        "isotropic cap, clamped edge": cap(tmp_path, boundary=[{"set": "edge"}], **r),
        "orthotropic with axes": from_mesh(tmp_path, plain, material={**ORTHO, "axes": AXES}, **r),
        "orthotropic without axes": from_mesh(tmp_path, plain, material=ORTHO, **r),
        "groups, isotropic default": from_mesh(tmp_path, groups, material=ISO, **r,
                                               materials={"CORE": {**ORTHO, "axes": AXES}, "SKIN": skin}),
        "groups, default with axes": from_mesh(tmp_path, groups, material={**ORTHO, "axes": AXES}, **r,
                                               materials={"CORE": ISO, "SKIN": {**ORTHO, "axes": [[0, 1, 0],
                                                                                                   [0, 0, 1]]}}),
    }
    if route == "stat_non_line":
        out["dkt shell"] = from_mesh(tmp_path, shell_plate_med(tmp_path, "quad"), material=ISO, element="dkt",
                                     thickness=0.003)
        out["coque_3d shell"] = from_mesh(tmp_path, shell_plate_med(tmp_path, "quad9"), material=ISO,
                                          element="coque_3d", thickness=0.003)
    return out


def rendered(ad, tmp_path, job: str, label: str) -> str:
    """The ``job`` command file (``forces`` or ``matrices``) the adapter renders, for 3 fields."""
    import re

    wd = Path(tmp_path) / re.sub(r"\W+", "_", f"{label}_{job}")
    wd.mkdir()
    ad.render_job(wd, job, n_fields=3)
    return (wd / f"{job}.comm").read_text()


def catalogue_variants(tmp_path) -> dict[str, str]:
    """Every command file variant the adapter renders (both force routes, both jobs): ``{label: text}``
    (what ``scripts/code_aster_catalogue.py`` checks against code_aster's catalogue and extracts facts from)."""
    out = {}
    for route in ("stat_non_line", "calcul"):
        folder = Path(tmp_path) / route
        folder.mkdir()
        for label, ad in catalogue_adapters(folder, route).items():
            for job in ("forces", "matrices"):
                out[f"{route}: {label}, {job}"] = rendered(ad, folder, job, label)
    return out


def install_fake_run_aster(folder: Path) -> Path:
    """:data:`FAKE_RUN_ASTER` written as the executable ``folder/bin/run_aster`` (for this interpreter)."""
    import stat
    import sys

    exe = folder / "bin" / "run_aster"
    exe.parent.mkdir()
    exe.write_text(FAKE_RUN_ASTER.format(python=sys.executable))
    exe.chmod(exe.stat().st_mode | stat.S_IEXEC)
    return exe

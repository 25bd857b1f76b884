"""Hostile scene and sweep files, model keys and polynomial systems: exit 2, a message, no traceback.

Every malformed file and every key out of its range must end as a
:class:`~stepnf.errors.SceneError` raised where that input enters (the TOML reader, the scene
check, the adapter's config check, the polynomial file loader): exit code 2 and a message naming
the file and the key. The cases are generated: for each key, several bad values of different kinds
(wrong type, out of range, huge, NaN, negative zero...). Runs that fail must leave an earlier
result file in the output folder byte-identical. Only the polynomial and von Karman adapters run
(no FE), plus FEniCSx config checks that fail before meshing.
"""
from __future__ import annotations

import io
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest

from helpers.hostile import assert_reported, run_cli, snapshot
from stepnf_polynomial import save_system
from helpers.systems import random_system
from helpers.paths import EXAMPLES

GOOD_ANALYSIS = 'master_modes = [0]\nmethods = ["nf", "dnf"]\n'

# TOML spellings of bad values, by kind
STRING, BOOL, TABLE, ARRAY, MIXED = '"two"', "true", "{ a = 1 }", "[1, 2]", '[1, "a", 2.5]'
HUGE_INT, NEG, NEG_ZERO, NAN, INF, DATE = str(2**70), "-1", "-0.0", "nan", "inf", "1979-05-27"
NOT_A_NUMBER = [STRING, BOOL, TABLE, ARRAY, MIXED, NAN, INF, DATE]


def scene_text(analysis: str = GOOD_ANALYSIS, step: str = "", output: str = "", model: str = "",
               top: str = "") -> str:
    """A polynomial scene with extra lines in each table."""
    return (f'{top}[model]\nsolver = "polynomial"\nfile = "s.npz"\n{model}\n[analysis]\n{analysis}\n'
            f'[analysis.step]\n{step}\n[output]\ndir = "out"\n{output}\n')


@pytest.fixture(scope="module")
def good_folder(tmp_path_factory):
    """A folder with a system, its scene and the result of a good run (``out/s.h5``)."""
    from stepnf.cli.main import main

    d = tmp_path_factory.mktemp("good")
    M, K, G, H = random_system(4, seed=5)
    save_system(d / "s.npz", M, K, G, H)
    (d / "s.toml").write_text(scene_text())
    assert main(["run", str(d / "s.toml"), "-q"]) == 0
    assert (d / "out" / "s.h5").is_file()
    return d


@pytest.fixture
def folder(good_folder, tmp_path):
    """A fresh copy of :func:`good_folder` for one case."""
    d = tmp_path / "case"
    shutil.copytree(good_folder, d)
    return d


def run_bad_scene(folder: Path, capsys, text: str | bytes, mentions) -> None:
    """Write ``s.toml``, run it: exit 2, no traceback, message naming the file and ``mentions``;
    the earlier result is untouched."""
    scene = folder / "s.toml"
    scene.write_bytes(text if isinstance(text, bytes) else text.encode("utf-8"))
    before = snapshot(folder / "out")
    outcome = run_cli(["run", scene, "-q"], capsys)
    assert_reported(outcome, codes=(2,), mentions=["s.toml", *mentions])
    assert snapshot(folder / "out") == before


# ------------------------------------------------------------------ encodings and TOML
ENCODED = {
    "binary garbage": bytes(np.random.default_rng(3).integers(0, 256, 300, dtype=np.uint8)) + b"\xff",
    "latin-1 accents": "# café, déformée\n".encode("latin-1") + scene_text().encode("ascii"),
    "utf-16 with BOM": scene_text().encode("utf-16"),
    "utf-16-le without BOM": scene_text().encode("utf-16-le"),
    "utf-32": scene_text().encode("utf-32"),
}


@pytest.mark.parametrize("kind", list(ENCODED))
def test_scene_not_utf8(folder, capsys, kind):
    run_bad_scene(folder, capsys, ENCODED[kind], ["UTF-8"])


def test_utf8_bom_is_fine(folder, capsys):
    scene = folder / "s.toml"
    scene.write_bytes(b"\xef\xbb\xbf" + scene_text().encode())
    assert run_cli(["run", scene, "-q"], capsys).code == 0


@pytest.mark.parametrize("text, mention", [
    ("[model\nsolver=", "not valid TOML"),
    ("", "model"),
    ("x = " + "[" * 3000 + "]" * 3000 + "\n", "TOML"),
    ("model = 1\n[analysis]\nmaster_modes = [0]\n", "model"),
    ('[[model]]\nsolver = "polynomial"\n', "model"),
    ('[model]\nsolver = 1\n[analysis]\nmaster_modes = [0]\n', "model.solver"),
    ('[model]\nsolver = ""\n[analysis]\nmaster_modes = [0]\n', "model.solver"),
    ('[model]\nsolver = "polynomial"\nanalysis = 3\n', "analysis"),
    (scene_text(top="[extra]\na = 1\n"), "extra"),
    (scene_text().replace("[analysis.step]\n", "step = 3\n"), "analysis.step"),
    (scene_text(output="").replace('[output]\ndir = "out"', "output = 1\n"), "output"),
])
def test_malformed_documents(folder, capsys, text, mention):
    run_bad_scene(folder, capsys, text, [mention])


def test_unreadable_scene_paths(tmp_path, capsys):
    (tmp_path / "d.toml").mkdir()
    for p in (tmp_path / "d.toml", tmp_path / "missing.toml"):
        assert_reported(run_cli(["run", p, "-q"], capsys), codes=(2,), mentions=[p.name])
    big = tmp_path / "big.toml"
    big.write_bytes(b"# " + b"x" * (5 * 2**20) + b"\n")
    assert_reported(run_cli(["run", big, "-q"], capsys), codes=(2,), mentions=["big.toml", "MiB"])


# ------------------------------------------------------------------ every [analysis] key
TOLERANCE_BAD = [STRING, BOOL, TABLE, ARRAY, NAN, INF, HUGE_INT, "0", NEG_ZERO, NEG, "2.0", "1e300"]
ANALYSIS_CASES = {
    "master_modes": [STRING, "[]", "[true]", "[-1]", f"[{HUGE_INT}]", "[0, 0]", "[[0]]", "[{ a = 1 }]",
                     '["(2,"]', '["(99999,0)"]', '[""]', "[1.5]", "7", "[1e300]"],
    "methods": ['"nf"', "[]", '["nf", "nf"]', "[1]", '[["nf"]]', '["NF"]', "[{ a = 1 }]", MIXED],
    "retained_modes": [STRING, BOOL, TABLE, ARRAY, "0", HUGE_INT, NEG, "1.5", NAN, DATE],
    "qm_order": ["1", '"none"', '["full"]', TABLE, BOOL],
    "tensors": ["1", '"all"', '["full"]', TABLE],
    "rigid_modes": ['"none"', BOOL, NEG, HUGE_INT, "1.5", TABLE, ARRAY],
    "rigid_tolerance": TOLERANCE_BAD,
    "degeneracy_tolerance": TOLERANCE_BAD,
    "resonance_tolerance": TOLERANCE_BAD,
    "coupling_tolerance": TOLERANCE_BAD,
    "linear_solver": ['"cholesky"', "1", "[]", TABLE],
    "deflation": ["1", '"yes"', TABLE, ARRAY],
    "max_modes": ["1", HUGE_INT, STRING, "3.0", BOOL, NEG, TABLE],
}
STEP_CASES = {
    "amplitude": ["1e308", "1e-300", "0", NEG, NEG_ZERO, STRING, BOOL, NAN, INF, HUGE_INT, ARRAY, TABLE],
    "relative_amplitude": ["0", NEG_ZERO, "1e9", "1e-300", STRING, BOOL, NAN, INF, HUGE_INT],
    "check": ["1", '"yes"', TABLE],
    "check_ratio": ["1.0", "0", "1e300", "1e-300", STRING, NEG, INF],
    "tolerance": ["0", "2", STRING, BOOL, NEG, NAN, INF],
    "method": ['"x"', "1", ARRAY],
}
OUTPUT_CASES = {
    "dir": ["1", '""', BOOL, ARRAY, TABLE, '"a\\u0000b"'],
    "name": ['"../evil"', '""', '"a/b"', '"."', '".."', "12", '"/abs/x"', '"a\\\\b"', '"tab\\tname"',
             '"' + "x" * 300 + '"', BOOL, ARRAY],
    "hdf5": ['"yes"', "1", TABLE],
    "plot": ["0", '"no"'],
    "fields": ["0", '"no"', ARRAY],
}


#: [analysis.backbone] (stepnf.keys.backbone): odd order in [3, 25], ascending positive lists, a relative
#: tolerance in (0, 1], a grid of 2..10000 points; a misspelt key names itself.
BACKBONE_CASES = {
    "order": ["4", "1", "27", "-3", "7.0", HUGE_INT, STRING, BOOL, NAN, ARRAY],
    "amplitudes": ["[]", "[2.0, 1.0]", "[1.0, 1.0]", "[0.0]", "[-1e-3]", "[1e300]", MIXED, STRING, NAN, TABLE],
    "w_over_h": ["[]", "[1.0, 0.5]", "[0]", "[1e9]", STRING, INF],
    "tolerance": ["0", "2", NEG, STRING, NAN, INF],
    "points": ["1", "0", "1e9", "2.5", STRING, BOOL],
    "ordr": ["7"],
}


def _cases(table: dict[str, list[str]]) -> list[tuple[str, str]]:
    return [(k, v) for k, values in table.items() for v in values]


@pytest.mark.parametrize("key, value", _cases(ANALYSIS_CASES))
def test_analysis_keys(folder, capsys, key, value):
    analysis = GOOD_ANALYSIS if key not in ("master_modes", "methods") else (
        'methods = ["nf"]\n' if key == "master_modes" else "master_modes = [0]\n")
    run_bad_scene(folder, capsys, scene_text(analysis=f"{analysis}{key} = {value}\n"), [f"analysis.{key}"])


@pytest.mark.parametrize("key, value", _cases(STEP_CASES))
def test_step_keys(folder, capsys, key, value):
    run_bad_scene(folder, capsys, scene_text(step=f"{key} = {value}\n"), [f"analysis.step.{key}"])


@pytest.mark.parametrize("key, value", _cases(BACKBONE_CASES))
def test_backbone_keys(folder, capsys, key, value):
    text = scene_text(analysis=f"{GOOD_ANALYSIS}[analysis.backbone]\n{key} = {value}\n")
    run_bad_scene(folder, capsys, text, [f"analysis.backbone.{key}"])


def test_backbone_both_lists_refused(folder, capsys):
    text = scene_text(analysis=f"{GOOD_ANALYSIS}[analysis.backbone]\namplitudes = [1e-3]\nw_over_h = [0.5]\n")
    run_bad_scene(folder, capsys, text, ["analysis.backbone.w_over_h", "not both"])


def test_backbone_w_over_h_needs_a_thickness(folder, capsys):
    """Decided by the model (the polynomial system has no transverse direction): refused at run time,
    still exit 2 naming the key, the earlier result untouched."""
    text = scene_text(analysis=f"{GOOD_ANALYSIS}thickness = 0.01\n[analysis.backbone]\nw_over_h = [0.5]\n")
    run_bad_scene(folder, capsys, text, ["analysis.backbone.w_over_h", "thickness"])


@pytest.mark.parametrize("key, value", _cases(OUTPUT_CASES))
def test_output_keys(folder, capsys, key, value):
    text = scene_text(output=f"{key} = {value}\n")
    if key == "dir":
        text = text.replace('dir = "out"\n', "")
    run_bad_scene(folder, capsys, text, [f"output.{key}"])
    assert sorted(p.name for p in folder.parent.iterdir()) == ["case"]  # nothing written beside the folder


def test_messages_say_what_is_allowed(folder, capsys):
    scene = folder / "s.toml"
    scene.write_text(scene_text(step="amplitude = 1e308\n"))
    err = run_cli(["run", scene, "-q"], capsys).err
    assert "[analysis.step.amplitude]" in err and "1e+308" in err and "[1e-15, 1e+15]" in err
    scene.write_text(scene_text(analysis=GOOD_ANALYSIS + 'retained_modes = "two"\n'))
    err = run_cli(["run", scene, "-q"], capsys).err
    assert "expected an integer in [1, 100000]" in err and "'two' (a string)" in err


# ------------------------------------------------------------------ polynomial systems
def npz_bytes(**arrays) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def crafted_npy(shape, descr="<f8", version=b"\x01\x00") -> bytes:
    """A .npy header announcing ``shape`` with (almost) no data after it."""
    header = repr({"descr": descr, "fortran_order": False, "shape": shape}).encode("latin-1")
    width = 2 if version == b"\x01\x00" else 4  # the header length field: 2 bytes in 1.0, 4 in 2.0
    header += b" " * (64 - (8 + width + len(header) + 1) % 64) + b"\n"
    return b"\x93NUMPY" + version + len(header).to_bytes(width, "little") + header + b"\x00" * 16


def zip_of(members: dict[str, bytes]) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        for name, data in members.items():
            z.writestr(name, data)
    return buf.getvalue()


def _system(n=4):
    M, K, G, H = random_system(n, seed=5)
    return {"M": M, "K": K, "G": G, "H": H}


def _bad_npz() -> dict[str, tuple[bytes, list[str]]]:
    s = _system()
    good = npz_bytes(**s)
    obj = np.empty(2, dtype=object)
    obj[:] = [1, 2]
    return {
        "random bytes": (bytes(range(256)) * 4, []),
        "empty file": (b"", []),
        "truncated zip": (good[: len(good) // 2], []),
        "zip missing H": (npz_bytes(M=s["M"], K=s["K"], G=s["G"]), ["missing arrays", "'H'"]),
        "empty zip": (zip_of({}), ["missing arrays"]),
        "G of the wrong shape": (npz_bytes(**{**s, "G": s["G"][:3]}), ["'G'"]),
        "M not square": (npz_bytes(**{**s, "M": np.ones((4, 3))}), ["'M'"]),
        "M a scalar": (npz_bytes(**{**s, "M": np.float64(1.0)}), ["'M'"]),
        "object array (pickle)": (npz_bytes(**{**s, "H": obj}), ["'H'", "object"]),
        "complex K": (npz_bytes(**{**s, "K": s["K"] + 0j}), ["'K'"]),
        "string M": (npz_bytes(**{**s, "M": np.array(["a", "b"])}), ["'M'"]),
        "NaN in K": (npz_bytes(**{**s, "K": np.full((4, 4), np.nan)}), ["K"]),
        "huge header M": (zip_of({"M.npy": crafted_npy((10**9, 10**9))}), ["'M'", "GiB"]),
        "huge header H": (zip_of({"M.npy": _npy(s["M"]), "K.npy": _npy(s["K"]), "G.npy": _npy(s["G"]),
                                  "H.npy": crafted_npy((10**5,) * 4)}), ["'H'", "GiB"]),
        "huge header v2": (zip_of({"M.npy": crafted_npy((10**9, 10**9), version=b"\x02\x00")}), ["'M'", "GiB"]),
        "header version 9": (zip_of({"M.npy": crafted_npy((4, 4), version=b"\x09\x00")}), ["'M'"]),
        "not an npy member": (zip_of({"M.npy": b"hello", "K.npy": b"x"}), ["'M'"]),
        "truncated data": (zip_of({**{f"{k}.npy": _npy(v) for k, v in s.items()},
                                   "H.npy": _npy(s["H"])[:-100]}), []),
        "length not a scalar": (npz_bytes(**s, length=np.ones(3)), ["length"]),
        "length negative": (npz_bytes(**s, length=np.float64(-1.0)), ["length"]),
        "directions out of range": (npz_bytes(**s, directions=np.full(4, 9)), ["directions"]),
        "coordinates NaN": (npz_bytes(**s, coordinates=np.full((4, 3), np.nan)), ["coordinates"]),
    }


def _npy(a) -> bytes:
    buf = io.BytesIO()
    np.save(buf, a)
    return buf.getvalue()


BAD_NPZ = _bad_npz()


@pytest.mark.parametrize("kind", list(BAD_NPZ))
def test_corrupt_npz(folder, capsys, kind):
    data, mentions = BAD_NPZ[kind]
    (folder / "s.npz").write_bytes(data)
    run_bad_scene(folder, capsys, scene_text(), ["model.file", "s.npz", *mentions])


@pytest.mark.parametrize("data", [b"\x89HDF\r\n\x1a\n" + b"x" * 200, b"garbage"])
def test_corrupt_hdf5_system(folder, capsys, data):
    (folder / "s.h5").write_bytes(data)
    run_bad_scene(folder, capsys, scene_text().replace('"s.npz"', '"s.h5"'), ["model.file", "s.h5"])


def test_hdf5_system_of_strings(folder, capsys):
    import h5py

    with h5py.File(folder / "s.h5", "w") as f:
        for k, v in _system().items():
            f[k] = v
        del f["H"]
        f["H"] = np.array([b"abc"])
    run_bad_scene(folder, capsys, scene_text().replace('"s.npz"', '"s.h5"'), ["model.file", "'H'"])


@pytest.mark.parametrize("value", ["12", BOOL, "[]", '""', TABLE, '"missing.npz"', '"s.txt"', '"a\\u0000b"'])
def test_polynomial_file_key(folder, capsys, value):
    text = scene_text().replace('file = "s.npz"', f"file = {value}")
    run_bad_scene(folder, capsys, text, ["model.file"])


def test_polynomial_header_message(folder, capsys):
    (folder / "s.npz").write_bytes(zip_of({"M.npy": crafted_npy((10**9, 10**9))}))
    scene = folder / "s.toml"
    scene.write_text(scene_text())
    err = run_cli(["run", scene, "-q"], capsys).err
    assert "(1000000000, 1000000000)" in err and "at most 1 GiB" in err


# ------------------------------------------------------------------ von Karman model keys
def vk_text(model: str) -> str:
    return (f'[model]\nsolver = "vonkarman"\n{model}\n[analysis]\nmaster_modes = ["(2,0)"]\nmethods = ["nf"]\n'
            '[output]\ndir = "out"\n')


VK_CASES = {
    "kappa": ["1e300", NEG, STRING, BOOL, NAN, INF, HUGE_INT, ARRAY, TABLE, "1e7"],
    "nu": ["0.5", NEG, "-1.0", STRING, BOOL, NAN, "1e300"],
    "k_max": ["100000", NEG, "2.5", '"8"', BOOL, HUGE_INT],
    "n_transverse": ["100000", "0", "1.5", STRING, HUGE_INT],
    "n_galerkin": ["100000", "5", STRING, NEG_ZERO],
    "n_airy": ["0", "1000000", STRING, BOOL, ARRAY],
}


@pytest.mark.parametrize("key, value", _cases(VK_CASES))
def test_vonkarman_keys(folder, capsys, key, value):
    model = f"{key} = {value}\n" + ("kappa = 25.0\n" if key != "kappa" else "")
    run_bad_scene(folder, capsys, vk_text(model), [f"model.{key}"])


def test_vonkarman_kappa_range_in_message(folder, capsys):
    scene = folder / "s.toml"
    scene.write_text(vk_text("kappa = 1e300\n"))
    err = run_cli(["run", scene, "-q"], capsys).err
    assert "[model.kappa]" in err and "[0, 1e+06]" in err


# ------------------------------------------------------------------ cap keys (FEniCSx, config time)
def fx_text(geometry: str = "", material: str = "", model: str = "") -> str:
    geo = {"shape": '"spherical_cap"', "a": "0.15", "R": "1.5", "h": "0.003"}
    mat = {"E": "1.04e11", "nu": "0.3", "rho": "4400.0"}
    for line in geometry.splitlines():
        k, v = line.split(" = ", 1)
        geo[k] = v
    for line in material.splitlines():
        k, v = line.split(" = ", 1)
        mat[k] = v
    return ('[model]\nsolver = "fenicsx"\n' + model + "[model.geometry]\n"
            + "".join(f"{k} = {v}\n" for k, v in geo.items()) + "[model.material]\n"
            + "".join(f"{k} = {v}\n" for k, v in mat.items())
            + '[analysis]\nmaster_modes = ["(2,0)"]\nmethods = ["dnf"]\n[output]\ndir = "out"\n')


CAP_CASES = [
    ("n_core = 100000", "model.geometry.n_core"),
    ("n_ring = 0", "model.geometry.n_ring"),
    ("n_thick = 2.5", "model.geometry.n_thick"),
    ('n_core = "14"', "model.geometry.n_core"),
    ("n_core = 300\nn_ring = 300", "dofs"),
    ("core = 0.9", "model.geometry.core"),
    (f"core = {HUGE_INT}", "model.geometry.core"),
    ("a = 1e300\nR = \"inf\"", "model.geometry.a"),
    ("a = 1e300", "model.geometry.a"),  # the length range before R >= a
    ("h = 1e-9", "model.geometry.h"),
    ("R = 1e300", "model.geometry.R"),
    ("R = -0.0", "model.geometry.R"),
    (f"h = {HUGE_INT}", "model.geometry.h"),
    ("a = true", "model.geometry.a"),
    ('R = "flat"', "model.geometry.R"),
]


@pytest.mark.parametrize("geometry, key", CAP_CASES)
def test_fenicsx_cap_keys(folder, capsys, geometry, key):
    run_bad_scene(folder, capsys, fx_text(geometry=geometry), [key])


@pytest.mark.parametrize("material, key", [("E = 1e300", "model.material.E"), ("rho = -0.0", "model.material.rho"),
                                           ('nu = "0.3"', "model.material.nu"), ("E = nan", "model.material.E")])
def test_fenicsx_material_keys(folder, capsys, material, key):
    run_bad_scene(folder, capsys, fx_text(material=material), [key])


@pytest.mark.parametrize("model, key", [("quadrature_degree = 2.0\n", "model.quadrature_degree"),
                                        (f"quadrature_degree = {HUGE_INT}\n", "model.quadrature_degree"),
                                        ('element = ["hex27"]\n', "model.element")])
def test_fenicsx_model_keys(folder, capsys, model, key):
    run_bad_scene(folder, capsys, fx_text(model=model), [key])


# ------------------------------------------------------------------ sweep files
def sweep_folder(folder: Path) -> Path:
    """A good base scene and a previous store (a sentinel the sweep must not touch)."""
    (folder / "base.toml").write_text(scene_text())
    return folder


def run_bad_sweep(folder: Path, capsys, text: str | bytes, mentions) -> None:
    sweep = folder / "sw.toml"
    sweep.write_bytes(text if isinstance(text, bytes) else text.encode("utf-8"))
    before = snapshot(folder.parent)
    outcome = run_cli(["sweep", sweep, "--quiet"], capsys)
    assert_reported(outcome, codes=(2,), mentions=["sw.toml", *mentions])
    assert snapshot(folder.parent) == before  # nothing written, inside the output folder or elsewhere


def sweep_text(sweep: str = "", dask: str = "", output: str = 'dir = "out"\n', vary: str | None = None) -> str:
    vary = '"analysis.retained_modes" = [2, 3]\n' if vary is None else vary
    return (f'[sweep]\nname = "st"\nbase = "base.toml"\n{sweep}[sweep.vary]\n{vary}[sweep.dask]\n{dask}'
            f"[output]\n{output}")


SWEEP_DASK_CASES = {
    "n_workers": [NEG, "0", HUGE_INT, "1.5", BOOL, '"2"', "100000", TABLE],
    "threads_per_worker": ['"two"', "0", NEG, HUGE_INT, "2.5", ARRAY],
    "scheduler": ["12", '""', '"tcp://a b"', BOOL, ARRAY],
}


@pytest.mark.parametrize("key, value", _cases(SWEEP_DASK_CASES))
def test_sweep_dask_keys(folder, capsys, key, value):
    run_bad_sweep(sweep_folder(folder), capsys, sweep_text(dask=f"{key} = {value}\n"), [f"sweep.dask.{key}"])


@pytest.mark.parametrize("value", ['"../evil"', '""', '"/abs/evil"', '"a/b"', '"."', '".."', "12", BOOL,
                                  '"a\\\\b"', '"new\\nline"'])
def test_sweep_name(folder, capsys, value):
    text = sweep_text().replace('name = "st"', f"name = {value}")
    run_bad_sweep(sweep_folder(folder), capsys, text, ["sweep.name"])


@pytest.mark.parametrize("text, key", [
    ('[sweep]\nscenes = "base.toml"\n', "sweep.scenes"),
    ("[sweep]\nscenes = []\n", "sweep.scenes"),
    ("[sweep]\nscenes = [1]\n", "sweep.scenes[0]"),
    ('[sweep]\nscenes = ["missing.toml"]\n', "sweep.scenes[0]"),
    ('[sweep]\nscenes = ["latin.toml"]\n', "sweep.scenes[0]"),
    ('[sweep]\nscenes = ["base.toml", "base.toml"]\n', "sweep"),
    ('[sweep]\nscenes = ["base.toml"]\nbase = "base.toml"\n', "sweep.scenes"),
    ("[sweep]\nbase = 12\n", "sweep.base"),
    ('[sweep]\nbase = "missing.toml"\n', "sweep.base"),
    ('[sweep]\nbase = "latin.toml"\n', "sweep.base"),
    ('[sweep]\nbase = "base.toml"\nvary = "x"\n', "sweep.vary"),
    ('[sweep]\nbase = "base.toml"\n[sweep.vary]\n"model.file" = "s.npz"\n', "sweep.vary.model.file"),
    ('[sweep]\nbase = "base.toml"\n[sweep.vary]\n"model.file" = []\n', "sweep.vary.model.file"),
    ('[sweep]\nbase = "base.toml"\n[sweep.vary]\n"nope.x" = [1]\n', "sweep.vary.nope.x"),
    ('[sweep]\nbase = "base.toml"\n[sweep.vary]\n"" = [1]\n', "sweep.vary."),
    ('[sweep]\nbase = "base.toml"\n[sweep.vary]\n"model..x" = [1]\n', "sweep.vary.model..x"),
    ('[sweep]\nbase = "base.toml"\n[sweep.vary]\n"model.file.x" = [1]\n', "sweep.vary.model.file.x"),
    ('[sweep]\nbase = "base.toml"\n[sweep.vary]\n"analysis.step.amplitude" = [1e308]\n', "sweep.vary"),
    ('[sweep]\nbase = "base.toml"\n[sweep.vary]\n"analysis.retained_modes" = [2, "two"]\n', "sweep.vary"),
    ('[sweep]\nbase = "base.toml"\n[sweep.vary]\n"analysis.retained_modes" = [2, 2]\n', "sweep"),
    ("[sweep]\nbase = \"base.toml\"\n[sweep.vary]\n" + "".join(
        f'"analysis.{k}" = {list(range(1, 31))}\n' for k in ("retained_modes", "max_modes", "rigid_modes")),
     "sweep.vary"),
    ('[sweep]\nbase = "base.toml"\n[output]\ndir = 3\n', "output.dir"),
    ('[sweep]\nbase = "base.toml"\n[output]\ncolour = 3\n', "output.colour"),
    ('[sweep]\nbase = "base.toml"\noutput = 1\n', "sweep.output"),
    ('[sweep]\nbase = "base.toml"\n[extra]\n', "extra"),
    ('output = 1\n[sweep]\nbase = "base.toml"\n', "output"),
    ('[sweep]\nbase = "base.toml"\ndask = 1\n', "sweep.dask"),
    ('[sweep]\nbase = "base.toml"\n[sweep.dask]\nworkers = 3\n', "sweep.dask.workers"),
    ("sweep = 1\n", "sweep"),
    ("", "sweep"),
])
def test_sweep_structure(folder, capsys, text, key):
    sweep_folder(folder)
    (folder / "latin.toml").write_bytes("# déformée\n".encode("latin-1") + scene_text().encode())
    run_bad_sweep(folder, capsys, text, [key])


SWEEP_ENCODED = {
    "binary garbage": ENCODED["binary garbage"],
    "latin-1 accents": "# déformée\n".encode("latin-1") + sweep_text().encode("ascii"),
    "utf-16 with BOM": sweep_text().encode("utf-16"),
    "utf-16-le without BOM": sweep_text().encode("utf-16-le"),
}


@pytest.mark.parametrize("kind", list(SWEEP_ENCODED))
def test_sweep_not_utf8(folder, capsys, kind):
    run_bad_sweep(sweep_folder(folder), capsys, SWEEP_ENCODED[kind], ["UTF-8"])


def test_sweep_name_outside_is_refused_with_allowed_form(folder, capsys):
    sweep_folder(folder)
    sweep = folder / "sw.toml"
    sweep.write_text(sweep_text().replace('name = "st"', 'name = "../../evil"'))
    err = run_cli(["sweep", sweep, "--quiet"], capsys).err
    assert "[sweep.name]" in err and "without '/'" in err and "'../../evil'" in err


# ------------------------------------------------------------------ external adapters' run keys (config time)
@pytest.mark.parametrize("solver, model, key", [
    ("calculix", "threads = 100000\n", "model.threads"),
    ("calculix", f"parallel_runs = {HUGE_INT}\n", "model.parallel_runs"),
    ("calculix", "timeout = 1e300\n", "model.timeout"),
    ("calculix", "executable = 12\n", "model.executable"),
    ("calculix", "template = [1]\n", "model.template"),
    ("code_aster", f"memory_mb = {HUGE_INT}\n", "model.memory_mb"),
    ("code_aster", "ncpus = 0\n", "model.ncpus"),
    ("code_aster", 'templates = ""\n', "model.templates"),
])
def test_external_run_keys(folder, capsys, solver, model, key):
    text = fx_text(model=model).replace('solver = "fenicsx"', f'solver = "{solver}"').replace(
        'shape = "spherical_cap"\n', "")
    run_bad_scene(folder, capsys, text, [key])


@pytest.mark.parametrize("solver", ["calculix", "code_aster"])
def test_external_cap_resolution(folder, capsys, solver):
    text = fx_text(geometry="n_core = 300\nn_ring = 300").replace('solver = "fenicsx"', f'solver = "{solver}"')
    run_bad_scene(folder, capsys, text, ["model.geometry.n_core", "dofs"])


def test_a_sweep_file_given_as_a_scene_says_so(capsys):
    """``stepnf run`` (or modes, check) on a sweep file points to ``stepnf sweep``, exit 2."""
    from pathlib import Path

    from stepnf.cli.main import main

    sweep = EXAMPLES / "table2.toml"
    assert main(["run", str(sweep), "-q"]) == 2
    err = capsys.readouterr().err
    assert "[sweep]: this is a sweep file, not a scene: run it with `stepnf sweep FILE`" in err

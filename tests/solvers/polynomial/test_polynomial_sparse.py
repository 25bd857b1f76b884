"""The polynomial adapter's sparse form (coordinate lists G_subs/G_vals, H_subs/H_vals, sparse M and K) from
.npz, HDF5 and MATLAB .mat (v5 through scipy, v7.3 through h5py): the same f as the dense form, the same
T and backbone through the pipeline, and bad lists as one-line input errors (exit 2) naming file and key.

References: the dense form of the same system (today's path, unchanged), and standard bounds on the
round-off of a sum (Higham, Accuracy and Stability of Numerical Algorithms, section 4.2).
"""
from __future__ import annotations

import numpy as np
import pytest
import scipy.io
import scipy.sparse as sp

from stepnf.cli.main import main
from stepnf.errors import SceneError
from stepnf.pipeline.run import run_scene
from stepnf.scene.parse import load_scene
from stepnf.testing.harness import parametrize_with_checks
from stepnf_polynomial import PolynomialAdapter, load_system, save_system
from stepnf_polynomial.sparse_tensors import CooTensor
from helpers.systems import random_system

N = 7
M, K, G, H = random_system(N, seed=11, rigid=1)
EPS = np.finfo(float).eps


def unsymmetric_lists(seed: int = 0):
    """Coordinate lists (0-based) of tensors that are NOT symmetric in their lower indices, with duplicated
    subscripts, whose f is that of the symmetric G, H: G + A with A antisymmetric in (j, k), and H + B with
    B = X - X^(j<->k) (its f vanishes); each list then cut in two halves that repeat every subscript."""
    rng = np.random.default_rng(seed)
    X = rng.standard_normal((N, N, N))
    Gn = G + X - X.transpose(0, 2, 1)
    Y = rng.standard_normal((N,) * 4)
    Hn = H + Y - Y.transpose(0, 2, 1, 3)
    out = []
    for T in (Gn, Hn):
        subs = np.argwhere(T)
        vals = T[tuple(subs.T)]
        w = rng.uniform(0.2, 0.8, len(vals))  # duplicated subscripts add up: w v + (1 - w) v = v
        out.append((np.concatenate([subs, subs]), np.concatenate([w * vals, (1 - w) * vals])))
    return out


GL, HL = unsymmetric_lists()


def sparse_adapter():
    return PolynomialAdapter(sp.csr_matrix(M), sp.csr_matrix(K), GL, HL)


@parametrize_with_checks(sparse_adapter)
def test_conformance(check):
    """The harness on the sparse path: slope = K, batch = loop, STEP = intrusive (the symmetric polar forms
    of unsymmetric lists), a symmetric tangent (f is conservative: the lists' f is the potential's)."""
    check()


def force_bound(U):
    """Higham's bound on the round-off of f = K u + G(u, u) + H(u, u, u) summed in any order: at most
    (terms per component) eps times the sum of |terms| (each product adds a few eps more: 2x margin)."""
    A = np.abs(U)
    scale = A @ np.abs(K).T + np.einsum("ijk,mj,mk->mi", np.abs(G), A, A) \
        + np.einsum("ijkl,mj,mk,ml->mi", np.abs(H), A, A, A)
    return 2 * (N + N ** 2 + N ** 3) * EPS * scale


def test_sparse_forces_equal_dense_ones():
    """Unsymmetric, duplicated lists give the dense symmetric system's f, polar forms and tangent to round-off.
    Fields of size 0.1 to 10 (linear and cubic terms in turn dominant)."""
    dense, sparse = PolynomialAdapter(M, K, G, H), sparse_adapter()
    rng = np.random.default_rng(5)
    U = rng.standard_normal((40, N)) * np.logspace(-1, 1, 40)[:, None]
    assert np.all(np.abs(sparse.internal_forces(U) - dense.internal_forces(U)) <= force_bound(U))
    u, v, w = U[38], U[39], U[37]
    # polar forms and tangent: the same sums with fewer terms, relative to their scale (|G||u||v| ~ 1e2 N^2)
    scale_g = np.abs(G).reshape(N, -1) @ np.abs(np.outer(u, v)).ravel()
    assert np.all(np.abs(sparse.quadratic_force(u, v) - dense.quadratic_force(u, v)) <= 4 * N ** 2 * EPS * scale_g)
    scale_h = np.abs(H).reshape(N, -1) @ np.abs(np.einsum("a,b,c->abc", u, v, w)).ravel()
    assert np.all(np.abs(sparse.cubic_force(u, v, w) - dense.cubic_force(u, v, w)) <= 12 * N ** 3 * EPS * scale_h)
    dT = (sparse.tangent_stiffness(u) - dense.tangent_stiffness(u)).toarray()
    assert np.abs(dT).max() <= 12 * N ** 3 * EPS * (np.abs(K).max() + np.abs(H).max() * N ** 2 * np.abs(u).max() ** 2
                                                     + np.abs(G).max() * N * np.abs(u).max())


def test_canonical_form_is_f_equivalent_and_short():
    """A symmetrised list shrinks to the monomials of f: N * C(N+1, 2) entries for G, N * C(N+2, 3) for H."""
    ad = sparse_adapter()
    assert (ad._Gs.nnz, ad._Hs.nnz) == (N * 28, N * 84)
    assert CooTensor.from_lists(np.array([[0, 1, 1], [0, 1, 1]]), np.array([1.0, -1.0]), 2).nnz == 0


def test_sparse_path_memory_is_order_nnz_plus_fields():
    """3000 dofs, banded lists: a dense G alone would take 216 GB. Forces of 50 fields, the polar forms and the
    tangent allocate at most one chunk of products (CHUNK_ENTRIES doubles) and a few arrays of nnz and m n."""
    import tracemalloc

    from stepnf_polynomial.sparse_tensors import CHUNK_ENTRIES

    n, m, rng = 3000, 50, np.random.default_rng(4)
    lists = []
    for order in (3, 4):
        i = np.repeat(np.arange(n), 5)
        subs = np.stack([i] + [np.clip(i + rng.integers(-3, 4, len(i)), 0, n - 1) for _ in range(order - 1)], axis=1)
        lists.append((subs, rng.standard_normal(len(i))))
    Md = sp.identity(n, format="csr")
    ad = PolynomialAdapter(Md, 2 * Md, *lists)
    nnz = ad._Gs.nnz + ad._Hs.nnz
    U = rng.standard_normal((m, n))
    tracemalloc.start()
    ad.internal_forces(U)
    ad.quadratic_force(U[0], U[1]), ad.cubic_force(U[0], U[1], U[2]), ad.tangent_stiffness(U[0])
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    # seen: 15 MB of a 40 MB bound
    assert peak <= 8 * (min(CHUNK_ENTRIES, nnz * m) + 20 * (nnz + m * n)), peak


@pytest.mark.parametrize("suffix", [".npz", ".h5"])
def test_npz_and_hdf5_round_trip(tmp_path, suffix):
    path = save_system(tmp_path / f"s{suffix}", sp.csr_matrix(M), sp.coo_matrix(K), GL, HL)
    data = load_system(path)
    assert isinstance(data["G"], CooTensor) and sp.issparse(data["M"])
    ad = PolynomialAdapter.from_config({"file": path.name}, base_dir=tmp_path)
    U = np.random.default_rng(1).standard_normal((3, N))
    # the same lists, read back bit for bit: the same canonical form, the same sums
    assert np.array_equal(ad.internal_forces(U), sparse_adapter().internal_forces(U))


def matlab_arrays(base: int = 1) -> dict:
    """What three lines of MATLAB export (docs/adapters.md): sparse M, K; 1-based double subs; column vals."""
    return {"M": sp.csc_matrix(M), "K": sp.csc_matrix(K), "directions": np.array([[0, 1, 2, 2, 1, 0, 2.0]]),
            "G_subs": (GL[0] + base).astype(float), "G_vals": GL[1][:, None],
            "H_subs": (HL[0] + base).astype(float), "H_vals": HL[1][:, None]}


def write_v73(path, arrays: dict) -> None:
    """A MATLAB v7.3 file as MATLAB lays it out: HDF5 behind a 512-byte text header, arrays column-major
    (a (k, 3) array is a (3, k) dataset), sparse matrices as groups (data, ir, jc, attribute MATLAB_sparse)."""
    import h5py

    with h5py.File(path, "w", userblock_size=512) as f:
        for name, a in arrays.items():
            if sp.issparse(a):
                a = sp.csc_matrix(a)
                g = f.create_group(name)
                g.attrs["MATLAB_class"] = np.bytes_("double")
                g.attrs["MATLAB_sparse"] = np.uint64(a.shape[0])
                g["data"], g["ir"], g["jc"] = a.data, a.indices.astype(np.uint64), a.indptr.astype(np.uint64)
            else:
                f[name] = np.asarray(a).T
                f[name].attrs["MATLAB_class"] = np.bytes_("double")
    with open(path, "r+b") as fp:
        fp.write(b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created by: stepnf tests HDF5 schema 1.00 .".ljust(116)
                 + b"\0" * 8 + b"\x00\x02IM")


@pytest.mark.parametrize("version", ["v5", "v7.3"])
def test_mat_round_trip_is_one_based(tmp_path, version):
    path = tmp_path / "beam.mat"
    if version == "v5":
        scipy.io.savemat(path, matlab_arrays())
    else:
        write_v73(path, matlab_arrays())
    ad = PolynomialAdapter.from_config({"file": "beam.mat"}, base_dir=tmp_path)
    U = np.random.default_rng(2).standard_normal((3, N))
    # 1-based subscripts shifted by one: the very lists of sparse_adapter(), hence the same sums bit for bit
    assert np.array_equal(ad.internal_forces(U), sparse_adapter().internal_forces(U))
    assert np.array_equal(ad.mass_matrix().toarray(), M)
    assert ad.dof_directions().tolist() == [0, 1, 2, 2, 1, 0, 2]  # MATLAB's row of doubles


@pytest.mark.parametrize("dims", [(0, 3), (3, 0)], ids=["matlab-order", "hdf5-order"])
def test_v73_empty_quadratic_tensor_is_read_as_zero(tmp_path, dims):
    """A model without a quadratic term (SSMTool's fnl{1} an empty sptensor: G.subs zeros(0, 3), G.vals
    zeros(0, 1)): in v7.3 MATLAB writes an empty array as a uint64 dataset of its dimensions with the
    attribute MATLAB_empty. Either order of those dimensions reads as G = 0: the forces are K u + H(u, u, u)
    bit for bit those of the same lists with G left out (no G entry to add)."""
    import h5py

    write_v73(tmp_path / "e.mat", matlab_arrays())
    with h5py.File(tmp_path / "e.mat", "r+") as f:
        for key, shape in (("G_subs", dims), ("G_vals", (0, 1))):
            del f[key]
            f[key] = np.array(shape, dtype=np.uint64)
            f[key].attrs["MATLAB_class"] = np.bytes_("double")
            f[key].attrs["MATLAB_empty"] = np.uint8(1)
    ad = PolynomialAdapter.from_config({"file": "e.mat"}, base_dir=tmp_path)
    U = np.random.default_rng(3).standard_normal((2, N))
    ref = PolynomialAdapter(sp.csr_matrix(M), sp.csr_matrix(K), (np.zeros((0, 3), np.int64), np.zeros(0)), HL)
    assert ad.describe()["tensors"]["nnz_G"] == 0
    assert np.array_equal(ad.internal_forces(U), ref.internal_forces(U))


def test_v5_sparse_matrices_are_not_sized_as_dense(tmp_path):
    """MATLAB's default save (v7, read by scipy) of a 12000-dof model: sparse M and K hold 12000 entries,
    not 12000^2 doubles (1.07 GiB, above the 1 GiB limit per array, which refused them before)."""
    n = 12000
    scipy.io.savemat(tmp_path / "big.mat", {"M": sp.identity(n, format="csc"), "K": sp.identity(n, format="csc"),
                                            "G_subs": np.array([[1.0, 1, 2]]), "G_vals": np.array([[1.0]]),
                                            "H_subs": np.array([[1.0, 1, 1, 1]]), "H_vals": np.array([[1.0]])})
    data = load_system(tmp_path / "big.mat")
    assert data["M"].shape == (n, n) and data["M"].nnz == n and data["G"].nnz == 1


SCENE = ('[model]\nsolver = "polynomial"\nfile = "{file}"\n[analysis]\nmaster_modes = [0, 2]\nmethods = ["dnf"]\n'
         '[analysis.backbone]\norder = 7\npoints = 5\n[output]\ndir = "{out}"\n')


def test_pipeline_gives_the_same_T_and_backbone(tmp_path):
    """A run on the sparse .mat file and on the dense .npz of the same system: same frequencies, T and backbone."""
    save_system(tmp_path / "dense.npz", M, K, G, H)
    scipy.io.savemat(tmp_path / "sparse.mat", matlab_arrays())
    runs = []
    for file, out in (("dense.npz", "d"), ("sparse.mat", "s")):
        (tmp_path / f"{out}.toml").write_text(SCENE.format(file=file, out=out))
        runs.append(run_scene(load_scene(tmp_path / f"{out}.toml")))
    dense, sparse = runs
    for a, b in zip(dense.modes, sparse.modes):
        # identical M and K (one dense eigen-solve of the same numbers) ...
        assert a.omega == b.omega
        # ... and forces equal to round-off (1e-15 relative, test_sparse_forces_equal_dense_ones), which
        # STEP's differences at probe amplitude q divide by q^2 (relative amplification ~1/q^2 ~ 1e1 here) and
        # the DPIM's shifted solves multiply by their condition (~1e2); seen: T 7e-16, omega ratio 2e-15,
        # amplitude 3e-14 (the root find A(rho)). 1e-10 leaves room for other BLAS orderings
        assert b.methods["dnf"].T == pytest.approx(a.methods["dnf"].T, rel=1e-10)
        assert np.allclose(b.backbone["omega_ratio"], a.backbone["omega_ratio"], rtol=1e-10, atol=0)
        assert np.allclose(b.backbone["amplitude"], a.backbone["amplitude"], rtol=1e-10, atol=0)


def bad_npz(tmp_path, change: dict) -> str:
    lists = {"G_subs": GL[0].copy(), "G_vals": GL[1].copy(), "H_subs": HL[0].copy(), "H_vals": HL[1].copy()}
    lists.update(change)
    np.savez(tmp_path / "bad.npz", M=M, K=K, **lists)
    return "bad.npz"


def bad_mat(tmp_path, change: dict) -> str:
    arrays = matlab_arrays()
    arrays.update(change)
    scipy.io.savemat(tmp_path / "bad.mat", arrays)
    return "bad.mat"


def half_pair(tmp_path, change: dict) -> str:
    """G_subs without G_vals."""
    np.savez(tmp_path / "bad.npz", M=M, K=K, G_subs=GL[0], H_subs=HL[0], H_vals=HL[1])
    return "bad.npz"


def bad_ir_v73(tmp_path, change: dict) -> str:
    """A v7.3 file whose sparse M has a row index past its rows (scipy does not check it: a segfault later)."""
    import h5py

    write_v73(tmp_path / "bad.mat", matlab_arrays())
    with h5py.File(tmp_path / "bad.mat", "r+") as f:
        ir = f["M/ir"][()]
        ir[3] = 10**6
        del f["M/ir"]
        f["M/ir"] = ir
    return "bad.mat"


def wrong_n(tmp_path, change: dict) -> str:
    """M and K as coordinate lists with an 'n' far above their entries (n = 1e9 was an out-of-memory kill:
    n-sized sparse arrays; 1e6 here keeps the code before the check from filling the machine)."""
    A, B = sp.coo_matrix(M), sp.coo_matrix(K)
    np.savez(tmp_path / "bad.npz", M_subs=np.stack([A.row, A.col], 1), M_vals=A.data, n=np.array(10**6),
             K_subs=np.stack([B.row, B.col], 1), K_vals=B.data, G_subs=GL[0], G_vals=GL[1], H_subs=HL[0],
             H_vals=HL[1])
    return "bad.npz"


G_OUT = GL[0].copy()
G_OUT[4, 2] = N  # one past the last dof (0-based)
G_ZERO = GL[0] + 1.0
G_ZERO[3, 1] = 0  # a 0 in MATLAB's 1-based subscripts
H_NAN = HL[1].copy()
H_NAN[10] = np.nan
G_HUGE = GL[0] + 1.0
G_HUGE[2, 0] = 1e30  # beyond int64: refused as a float, not cast with a warning on stderr (review of issue 35)


@pytest.mark.parametrize("write, change, expected", [
    (bad_npz, {"G_subs": G_OUT}, r"array 'G_subs' row 4 holds subscripts \[\d+, \d+, 7\] outside 0..6"),
    (bad_mat, {"G_subs": G_ZERO}, r"array 'G_subs' row 4 holds .* outside 1..7 .*1-based: a 0 is never one"),
    (bad_npz, {"G_vals": GL[1][:-1]}, r"arrays 'G_subs' and 'G_vals' differ in length"),
    (bad_npz, {"H_vals": H_NAN}, r"array 'H_vals' holds NaN or inf \(entry 10"),
    (bad_mat, {"H_subs": HL[0][:, :3] + 1.0}, r"array 'H_subs' has shape \(\d+, 3\), expected \(k, 4\)"),
    (half_pair, {}, r"missing array 'G_vals' next to 'G_subs'"),
    (bad_mat, {"G_subs": {"subs": 1.0}}, r"variable 'G_subs' is a MATLAB struct; export plain arrays"),
    (bad_ir_v73, {}, r"sparse variable 'M' is inconsistent \(row index values must be < 7\)"),
    (wrong_n, {}, r"array 'n' says 1000000 dofs but M and K hold \d+ entries"),
    (bad_mat, {"G_subs": G_HUGE}, r"array 'G_subs' row 3 holds subscripts \[1e\+30, .* outside 1..7"),
], ids=["out_of_range", "zero_in_matlab", "lengths", "nan", "subs_width", "half", "struct", "v73_bad_ir", "wrong_n",
        "huge"])
def test_bad_lists_are_one_line_input_errors(tmp_path, capsys, write, change, expected):
    file = write(tmp_path, change)
    (tmp_path / "s.toml").write_text(SCENE.format(file=file, out="out"))
    with pytest.raises(SceneError, match=expected):
        PolynomialAdapter.from_config({"file": file}, base_dir=tmp_path, scene_file=tmp_path / "s.toml")
    assert main(["run", str(tmp_path / "s.toml"), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    assert "s.toml" in err and "[model.file]" in err and file in err and "corrupt" not in err

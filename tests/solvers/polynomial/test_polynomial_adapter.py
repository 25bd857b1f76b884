"""The polynomial adapter passes the conformance harness and reads .npz and HDF5 alike."""
import numpy as np
import pytest

from stepnf.errors import SceneError
from stepnf.testing.harness import parametrize_with_checks
from stepnf_polynomial import PolynomialAdapter, load_system, save_system
from helpers.systems import random_system

M, K, G, H = random_system(7, seed=11, rigid=1)


@parametrize_with_checks(lambda: PolynomialAdapter(M, K, G, H))
def test_conformance(check):
    check()


def test_harness_catches_a_wrong_K():
    """The slope check must fail when K does not match f (a harness that cannot fail proves nothing)."""
    ad = PolynomialAdapter(M, K * 1.001, G, H)
    ad._K = K * 1.001
    bad = PolynomialAdapter(M, K, G, H)
    bad.stiffness_matrix = lambda: __import__("scipy.sparse").sparse.csr_matrix(K * 1.001)
    from stepnf.testing.harness import Tolerances, check_slope_equals_K

    with pytest.raises(AssertionError, match="slope"):
        check_slope_equals_K(bad, Tolerances())


@pytest.mark.parametrize("suffix", [".npz", ".h5"])
def test_file_round_trip(tmp_path, suffix):
    path = save_system(tmp_path / f"s{suffix}", M, K, G, H)
    ad = PolynomialAdapter.from_config({"file": path.name}, base_dir=tmp_path)
    u = np.linspace(-1, 1, 7) * 0.1
    ref = PolynomialAdapter(M, K, G, H).internal_force(u)
    assert np.allclose(ad.internal_force(u), ref, rtol=1e-14, atol=0)
    assert load_system(path)["H"].shape == (7, 7, 7, 7)


def test_missing_array_is_a_clear_error(tmp_path):
    np.savez(tmp_path / "s.npz", M=M, K=K, G=G)
    with pytest.raises(SceneError, match=r"model.file.*missing arrays \['H'\]"):
        PolynomialAdapter.from_config({"file": "s.npz"}, base_dir=tmp_path, scene_file=tmp_path / "x.toml")


def test_wrong_shape_and_unknown_key(tmp_path):
    with pytest.raises(ValueError, match="array G has shape"):
        PolynomialAdapter(M, K, G[:3], H)
    with pytest.raises(SceneError, match="unknown key"):
        PolynomialAdapter.from_config({"file": "s.npz", "mesh": "x"}, base_dir=tmp_path)

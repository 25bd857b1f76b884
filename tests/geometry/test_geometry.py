"""Tests of the spherical-cap generator (pure numpy, fast)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from stepnf.geometry import ModeLabeler, jacobians, outward_normals, shell_volume, spherical_cap, volume
from stepnf.geometry.hexahedra import gauss_points, shape_functions

A, H = 0.15, 0.003
CASES = [(float("inf"), "hex27"), (1.5, "hex27"), (0.3, "hex27"), (1.5, "hex20")]


@pytest.mark.parametrize("R, element", CASES)
def test_volume_jacobians_and_nodes(R, element):
    mesh = spherical_cap(A, R, H, element=element, n_core=6, n_ring=3)
    V, V_exact = volume(mesh.points, mesh.cells), shell_volume(A, R, H)
    # the only geometric error is the quadratic interpolation of the circular
    # edge, 24 arcs of pi/12: relative area error ~ (pi/12)^4 / 100 ~ 5e-5
    assert abs(V - V_exact) <= 5e-5 * V_exact
    xi, _ = gauss_points(3)
    corners = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 1], [0, 1, 1]], float)
    assert jacobians(mesh.points, mesh.cells, np.vstack([xi, corners])).min() > 0
    key = np.round(mesh.points / (1e-9 * A)).astype(np.int64)
    assert len(np.unique(key, axis=0)) == mesh.n_points, "duplicate nodes"
    assert np.array_equal(np.unique(mesh.cells), np.arange(mesh.n_points)), "orphan nodes"
    assert mesh.cells.shape[1] == (27 if element == "hex27" else 20)


def test_volume_converges_at_fourth_order():
    # quadratic arcs approximate the circle with an area error O(dtheta^4)
    n = np.array([4, 8, 16])
    err = [abs(volume(m.points, m.cells) - shell_volume(A, 1.5, H))
           for m in (spherical_cap(A, 1.5, H, n_core=k, n_ring=2) for k in n)]
    rate = np.polyfit(np.log(n), np.log(err), 1)[0]
    assert rate < -3.8


@pytest.mark.parametrize("R", [float("inf"), 1.5])
def test_midsurface_on_sphere_and_through_thickness(R):
    mesh = spherical_cap(A, R, H, n_thick=2)
    mid = mesh.points[mesh.midsurface]
    r_plan = np.hypot(mid[:, 0], mid[:, 1])
    assert r_plan.max() == pytest.approx(A, rel=1e-12)
    if math.isinf(R):
        assert np.abs(mid[:, 2]).max() == 0.0
        assert np.ptp(mesh.points[:, 2]) == pytest.approx(H, rel=1e-12)
    else:
        dist = np.linalg.norm(mesh.points - [0, 0, -R], axis=1)
        assert np.allclose(np.linalg.norm(mid - [0, 0, -R], axis=1), R, rtol=1e-14)
        assert dist.min() == pytest.approx(R - H / 2, rel=1e-14)
        assert dist.max() == pytest.approx(R + H / 2, rel=1e-14)
        assert mid[:, 2].max() == 0.0  # apex at the origin, dome curving downwards
    # (2 n_thick + 1) node levels, one of them the mid-surface
    assert mesh.n_points == 5 * int(mesh.midsurface.sum())


@pytest.mark.parametrize("n_nodes", [8, 20, 27])
def test_shape_functions_partition_of_unity_and_kronecker(n_nodes):
    from stepnf.geometry.hexahedra import HEX27_NODES

    N, dN = shape_functions(HEX27_NODES[:n_nodes], n_nodes)
    assert np.allclose(N, np.eye(n_nodes), atol=1e-14)
    xi = np.random.default_rng(0).random((5, 3))
    N, dN = shape_functions(xi, n_nodes)
    assert np.allclose(N.sum(1), 1.0, atol=1e-14) and np.allclose(dN.sum(1), 0.0, atol=1e-13)
    # gradients reproduce linear fields: sum_a x_a dN_a = I
    assert np.allclose(np.einsum("ak,qad->qkd", HEX27_NODES[:n_nodes], dN), np.eye(3), atol=1e-13)


@pytest.mark.parametrize("kwargs, match", [
    ({"element": "hex8"}, "hex27"), ({"h": -1.0}, "h > 0"), ({"R": 0.1}, "R >= a"), ({"n_core": 0}, "n_core"),
])
def test_bad_arguments(kwargs, match):
    args = {"a": A, "R": 1.5, "h": H} | kwargs
    with pytest.raises(ValueError, match=match):
        spherical_cap(**args)


# ----------------------------------------------------------------- labels
def _labeler(R=math.inf):
    mesh = spherical_cap(A, R, H, n_core=8, n_ring=4)

    mid = np.nonzero(mesh.midsurface)[0]
    return mesh, ModeLabeler(mesh.points[mid, :2], mid, outward_normals(mesh.points, R), A)


@pytest.mark.parametrize("R", [math.inf, 0.5])
@pytest.mark.parametrize("k, n", [(0, 1), (0, 2), (2, 0), (3, 0), (1, 1), (4, 2), (2, 1)])
def test_labels_of_synthetic_transverse_fields(R, k, n):
    """w = r^k cos(k theta + 0.3) P(r) with n simple roots of P inside the disk -> (k, n)."""
    mesh, lab = _labeler(R)

    x, y = mesh.points[:, 0] / A, mesh.points[:, 1] / A
    r, t = np.hypot(x, y), np.arctan2(y, x)
    roots = np.linspace(0.45 + 0.04 * k, 0.85, n) if n else []
    w = r**k * np.cos(k * t + 0.3) * np.prod([r - c for c in roots], axis=0) + (0.2 if (k, n) == (0, 1) else 0)
    U = w[:, None] * outward_normals(mesh.points, R)
    assert lab.label(U) == (k, n)


def test_labels_of_in_plane_and_thickness_fields():
    mesh, lab = _labeler()
    x, y, z = mesh.points.T
    in_plane = np.column_stack([x, y, 0 * z])  # radial breathing
    assert lab.label(in_plane) == "in-plane"
    thickness = np.column_stack([0 * x, 0 * y, z])  # through-thickness stretching, zero on the mid-surface
    assert lab.label(thickness) == "thickness"


def test_shared_cap_scene_keys(tmp_path):
    """The keys every cap adapter accepts: impossible caps and materials are refused, naming the key."""
    import pytest

    from stepnf.errors import SceneError
    from stepnf.geometry import keys

    good = {"geometry": {"a": 0.15, "R": "inf", "h": 0.003, "n_core": 4},
            "material": {"E": 1e11, "nu": 0.3, "rho": 4e3}}
    g = keys.cap_geometry(good, None)
    assert g["R"] == float("inf") and g["resolution"] == {"n_core": 4}
    bad = [({"geometry": {"a": 0.15, "R": 0.1, "h": 0.003}}, "model.geometry.R"),  # R < a
           ({"geometry": {"a": 0.15, "R": 2.0, "h": 0.0}}, "model.geometry.h"),
           ({"geometry": {"a": 0.15, "R": 2.0, "h": -1e-3}}, "model.geometry.h"),
           ({"geometry": {"a": 0.15, "R": 2.0, "h": 0.2}}, "model.geometry.h"),  # h >= a
           ({"geometry": {"a": 0.15, "R": 2.0, "h": 0.003, "shape": "torus"}}, "model.geometry.shape")]
    for cfg, key in bad:
        with pytest.raises(SceneError) as e:
            keys.cap_geometry(cfg, tmp_path / "s.toml")
        assert e.value.key == key
    for mat, key in [({"E": 1.0, "nu": 0.5, "rho": 1.0}, "model.material.nu"),
                     ({"E": -1.0, "nu": 0.3, "rho": 1.0}, "model.material.E"),
                     ({"E": 1.0, "nu": 0.3}, "model.material.rho")]:
        with pytest.raises(SceneError) as e:
            keys.material({"material": mat}, None)
        assert e.value.key == key

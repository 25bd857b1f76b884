"""``stepnf verify`` on a cantilever (issue 31, item 5): the full model's orbits at tip deflections of one
and two thicknesses, where the modified Newton of the time integration (iteration matrix built on K)
does not converge.

The model: tests/helpers/beam.py's slender beam (L/h = 100, width 2 h, 20 x 1 x 1 hex27 cells, 1080
dofs), clamped at x = 0 only, by FEniCSx (no tangent stiffness: the integration's Newton has only the
forces). Before the secant and Newton-Krylov stages (stepnf/verify/integrate.py, krylov.py) the orbit
at W_max/h = 2 failed at its first step ("Newton did not converge at t = 0.00167347 (step 1 ...)",
exit 3): J0^-1 J has ~20 eigenvalues away from 1 by 0.5 to 10 there (the membrane-bending coupling),
which Anderson's memory of 5 cannot absorb.
"""
from __future__ import annotations

import json
import time

import numpy as np
import pytest

from helpers.beam import HB, beam_mesh, beam_scene
from helpers.scenes import run_verify

pytestmark = [pytest.mark.fenicsx, pytest.mark.slow]


#: q = phi^T M x of the first bending mode at tip deflections of h and 2 h: phi's tip is 2 / sqrt(m) for
#: the mass-normalised Euler-Bernoulli mode (m = rho B HB L = 1.56 kg), 1.60; measured below
AMPLITUDES = (0.00625, 0.0125)


def write_cantilever(folder) -> str:
    meshio = pytest.importorskip("meshio")
    pts, cells = beam_mesh((20, 1, 1))
    meshio.Mesh(pts, [("hexahedron27", cells)]).write(folder / "cantilever.vtu")
    clamp = [{"box": [[0.0, -1.0, -1.0], [0.0, 1.0, 1.0]]}]  # the face x = 0 only
    path = folder / "cantilever.toml"
    path.write_text(beam_scene("cantilever.vtu", clamp, methods=("dnf",), analysis="[analysis.backbone]\norder = 7"))
    return str(path)


def test_cantilever_verifies_at_two_thicknesses(tmp_path, capsys):
    """Both orbits computed (exit 0), at W_max/h = 1 and 2, and the backbone within 1e-4 of them.

    The 1e-4 bound: the integration's own accuracy at the default rtol (1e-6, Richardson over dt and
    dt/2) and the DPIM order-7 truncation far inside its validity range (the frequency moves by only
    ~1.3e-5 at W_max/h = 2: a cantilever's first mode is weakly nonlinear; measured differences
    -4.3e-7 and -2.6e-6). The W_max/h = 2 orbit needs the secant stage at every step (measured: 217 + 434
    steps, ~10 iterations each, no Newton-Krylov, no halving); 70-100 s for both orbits on a shared machine.
    """
    path = write_cantilever(tmp_path)
    t0 = time.perf_counter()
    code, out, err = run_verify(capsys, path, "--amplitudes", *AMPLITUDES, "--json", "--quiet")
    seconds = time.perf_counter() - t0
    assert code == 0, err
    doc = json.loads(out)
    assert doc["method"] == "integration" and doc["n_dofs"] == 1080
    (mode,) = doc["modes"]
    assert not mode.get("failed")
    checks = mode["checks"]
    assert [c["amplitude"] for c in checks] == list(AMPLITUDES)
    tips = [c["max_displacement"] / HB for c in checks]
    # the tip deflection of the starting state (turning point): 1 and 2 thicknesses (Euler-Bernoulli's
    # 1.60 q: 1.0 and 2.0; the 3D beam's mode and its quadratic part 0.2% more, measured 1.002 and 2.004)
    assert tips == pytest.approx([1.0, 2.0], rel=0.01)
    for c in checks:
        assert abs(c["relative_difference"]) < 1e-4, c
        assert c["orbit_amplitude"] == pytest.approx(c["amplitude"], rel=1e-3)
    # the second orbit is the one the modified Newton could not do: the secant stage did it, every step
    work = checks[1]["work"]["levels"]
    assert all(lv["secant_steps"] > 0 for lv in work)
    assert all(lv["halved_steps"] == 0 for lv in work)
    with capsys.disabled():
        rows = [f"W/h = {t:.3f}: w_check/w - 1 = {c['omega_check_over_omega'] - 1:.3e}, rel. diff "
                f"{c['relative_difference']:.2e}, {sum(lv['newton_iterations'] for lv in c['work']['levels'])} "
                f"Newton iterations, {c['seconds']:.1f} s" for t, c in zip(tips, checks)]
        print("\n  cantilever verify: " + "; ".join(rows) + f" ({seconds:.1f} s)")


@pytest.mark.parametrize("args,words", [
    (("--tangent", "tangent"), ["--tangent tangent", "no tangent stiffness", "differences"]),
    (("--steps-per-period", "4"), ["--steps-per-period", "[8, 100000]"]),
])
def test_bad_keys_exit_2(tmp_path, capsys, args, words):
    """FEniCSx gives no tangent: --tangent tangent is refused before the run (exit 2), as is a step count
    out of range; the message names the key and what is allowed."""
    code, _, err = run_verify(capsys, write_cantilever(tmp_path), "--amplitudes", AMPLITUDES[0], *args, "--quiet")
    assert code == 2, err
    assert all(w in err for w in words) and "Traceback" not in err, err

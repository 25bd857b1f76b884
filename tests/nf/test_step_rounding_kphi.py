"""STEP's per-entry rounding bound is written once (:func:`stepnf.nf.roundoff.step_rounding`): the
truncation ladder's rounding (:func:`stepnf.step.truncation.rounding_of_step`) passes ``K phi`` it already
has (no sparse product per call) and the floor ``eps`` of a full-precision force."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from stepnf.linalg.null_space import abs_product
from stepnf.nf.roundoff import EPS, step_rounding, weighted_rounding
from stepnf.step.truncation import rounding_of_step


def test_kphi_given_and_the_floor_are_the_same_bound():
    rng = np.random.default_rng(3)
    K = sp.random(40, 40, density=0.2, random_state=4, format="csr") + sp.identity(40)
    phi, Gv, Hv = rng.standard_normal((3, 40))
    kp = abs_product(K, np.abs(phi))[:, 0]
    q = 0.01
    for digits in (None, 6):
        own, printed = step_rounding(kp, K, phi, q, Gv, Hv, digits)
        own2, printed2 = step_rounding(kp, None, phi, q, Gv, Hv, digits, Kphi=K @ phi)
        np.testing.assert_array_equal(own2, own)  # the same arithmetic: bit for bit
        np.testing.assert_array_equal(printed2, printed)
        floored = step_rounding(kp, None, phi, q, Gv, Hv, digits, Kphi=K @ phi, floor=EPS)[1]
        f = np.abs(q * (K @ phi) + q * q * Gv + q ** 3 * Hv)
        # the floor: eps |f_i| at full precision (digits None: printed 0), 0.5e-5 |f_i| above it
        np.testing.assert_array_equal(floored, (EPS if digits is None else 0.5e-5) * f)
        rG, rh = rounding_of_step(kp, K @ phi, phi, q, Gv, Hv, digits)
        assert rG == float(np.linalg.norm(own + floored)) / q ** 2
        assert rh == weighted_rounding(np.abs(phi), own, floored) / q ** 3

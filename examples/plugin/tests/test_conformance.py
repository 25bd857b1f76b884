"""The plugin's own tests: stepnf's conformance harness on the truss adapter, one pytest id per check, and
the same harness catching a deliberately wrong variant of it."""
from stepnf.testing import run_checks

# [guide:conformance]
from stepnf.testing import parametrize_with_checks
from stepnf_truss import TrussAdapter

PINNED = {"panels": 4, "boundary": [{"set": "ends"}]}  # a [model] table, as a scene gives it


@parametrize_with_checks(lambda: TrussAdapter(**PINNED), config=PINNED)
def test_conformance(check):
    check()
# [/guide:conformance]


# [guide:wrong]
class WrongStressMeasure(TrussAdapter):
    """N times the *reference* bar vector: f(0) = 0 and df/du(0) = K still hold, but the tangent
    EA/L0^3 d0 d^T is not symmetric once the bars have turned, so f is the gradient of no energy."""

    provides_tangent_stiffness = False
    provides_intrusive_tensors = False

    def _internal_force(self, u):
        d, e = self.bar_states(u)
        return self.nodal((self.EA * e / self.L0)[:, None] * self.d0)
# [/guide:wrong]


def test_the_harness_catches_a_wrong_stress_measure():
    status = {r.name: r.status for r in run_checks(lambda: WrongStressMeasure(**PINNED))}
    assert status.pop("conservative_force") == "failed"
    assert status.pop("step_equals_intrusive") == "skipped"  # no intrusive tensors declared
    assert status.pop("transverse_displacements") == "skipped"  # a truss offers no transverse map
    assert set(status.values()) == {"passed"}, status

"""The conformance harness of solver adapters (in the spirit of scikit-learn's ``parametrize_with_checks``):
the checks (:mod:`.harness`), what they share (:mod:`.base`) and the checks of an adapter's ``[model]``
keys (:mod:`.model_keys`). An adapter's test suite imports from here::

    from stepnf.testing import parametrize_with_checks
"""
from __future__ import annotations

from typing import TYPE_CHECKING

from stepnf.runtime.lazy import lazy_exports

if TYPE_CHECKING:
    from stepnf.testing.harness import (CHECKS, CheckResult, CheckSkipped, Tolerances, adapter_checks,
                                        parametrize_with_checks, run_checks)

_NAMES = {name: "harness" for name in ("CHECKS", "CheckResult", "CheckSkipped", "Tolerances", "adapter_checks",
                                        "parametrize_with_checks", "run_checks")}
__getattr__ = lazy_exports(__name__, _NAMES, globals())
__all__ = sorted(_NAMES)

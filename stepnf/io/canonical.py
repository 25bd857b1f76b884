"""Canonical JSON: the one text of a JSON-able value by which stored keys are compared, hashed and kept.

Sorted keys, Python's default separators, anything not JSON-able as its ``str`` (a path). Used by
:mod:`stepnf.scene.model_key` (:func:`~stepnf.scene.model_key.digest` hashes it, a sweep store keeps it) and by
:mod:`stepnf.step.checkpoint` (``model_key.json``): a leaf module, so that both import it without a circle.
"""
from __future__ import annotations

import json
from typing import Any


def dumps(value: Any) -> str:
    """``value`` as canonical JSON (sorted keys; a value JSON cannot hold, as its ``str``)."""
    return json.dumps(value, sort_keys=True, default=str)

"""The conformance checks of an adapter's ``[model]`` keys and of ``from_config`` (:mod:`stepnf.testing.harness`)."""
from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from stepnf.plugin.adapter import SolverAdapter
from stepnf.errors import SceneError
from stepnf.keys.schema import KINDS, Key, Schema
from stepnf.testing.base import CheckSkipped, Tolerances, maxabs, random_fields


def check_model_keys(adapter: SolverAdapter, tol: Tolerances) -> None:
    """The declared ``[model]`` keys are a :class:`Schema` of valid :class:`Key` s whose defaults pass their
    own check (and, with no required key, the schema's check as one table). ``validate_config`` is not
    called: its checks across keys ("a mesh or a deck") may refuse any table of defaults alone."""
    cls = type(adapter)
    schema = cls.model_schema()
    if schema is None:
        raise CheckSkipped(f"{cls.__name__} declares no [model] keys (model_schema() is None)")
    assert isinstance(schema, Schema), f"model_schema() returned {type(schema).__name__}, expected a Schema"
    defaults, bad = {}, []
    with tempfile.TemporaryDirectory() as base:
        for key in schema:
            if not isinstance(key, Key) or key.kind not in KINDS:
                bad.append(f"{key!r}: not a Key of a known kind")
            elif key.default is not None and key.kind not in ("file", "folder"):  # those must exist
                try:
                    key.check(key.default, file=None, where="model", base_dir=base)
                    defaults[key.name] = key.default
                except SceneError as exc:
                    bad.append(f"default of {key.name!r}: {exc}")
        if not bad and not any(k.required for k in schema):  # the defaults together, as a [model] table
            try:
                schema.check(defaults, where="model", base_dir=base, reserved=("solver",))
            except SceneError as exc:
                bad.append(f"the defaults together {defaults}: {exc}")
    assert not bad, "the declared [model] keys are broken: " + "; ".join(bad)


def _documented_defaults(schema: Schema, given: Mapping[str, Any]) -> dict[str, Any]:
    """The declared defaults of the keys ``given`` leaves out (files and folders excepted: they must exist)."""
    return {k.name: k.default for k in schema
            if k.default is not None and k.kind not in ("file", "folder") and k.name not in given}


def _same_model(a: SolverAdapter, b: SolverAdapter, tol: Tolerances) -> str:
    """'' when ``a`` and ``b`` have the same dofs, K, M and force at one field, else what differs."""
    if a.n_dofs != b.n_dofs:
        return f"{a.n_dofs} dofs against {b.n_dofs}"
    for name, A, B in (("K", a.stiffness_matrix(), b.stiffness_matrix()), ("M", a.mass_matrix(), b.mass_matrix())):
        diff = maxabs(A - B) / max(maxabs(A), 1e-300)
        if diff > tol.batch:
            return f"{name} differs by {diff:.3e} (relative)"
    u = random_fields(a, 1, seed=7)
    fa, fb = a.internal_forces(u), b.internal_forces(u)
    diff = float(np.max(np.abs(fa - fb))) / max(float(np.max(np.abs(fa))), 1e-300)
    return f"the internal force differs by {diff:.3e} (relative)" if diff > tol.batch else ""


def check_from_config(adapter: SolverAdapter, tol: Tolerances, config: Mapping[str, Any] | None = None,
                      base_dir: str | Path | None = None) -> None:
    """``from_config`` builds an adapter from a ``[model]`` table, and its documented defaults hold.

    The table is ``config`` (a scene's ``[model]`` without ``solver``; paths from ``base_dir``), else the
    empty one. It must build an adapter (a SceneError for a given table, or any other exception, fails);
    completed with the defaults the keys *document* (``Key.default``: shown, never applied by stepnf) it
    must build the same model (dofs, K, M, the force at one field, to ``batch``). Skipped without declared
    keys, with a required key and no table, or when the defaults alone are refused with a message (checks
    across keys: "a mesh or a geometry"). Every adapter built is closed.
    """
    cls = type(adapter)
    schema = cls.model_schema()
    if config is None:
        if schema is None:
            raise CheckSkipped(f"{cls.__name__} declares no [model] keys: give the harness a [model] table "
                               "(config=) to check from_config")
        required = [k.name for k in schema if k.required]
        if required:
            raise CheckSkipped(f"{cls.__name__} has required [model] keys {required}: give the harness a [model] "
                               "table (config=) to check from_config")
    table = dict(config or {})
    with tempfile.TemporaryDirectory() as tmp:
        base = Path(base_dir) if base_dir is not None else Path(tmp)
        built: list[SolverAdapter] = []

        def build(cfg: Mapping[str, Any], what: str) -> SolverAdapter:
            try:
                model = cls.from_config(cfg, base_dir=base, scene_file=None)
            except SceneError as exc:
                if config is None and not built:
                    raise CheckSkipped(f"the defaults alone make no model ({exc}): give the harness a [model] "
                                       "table (config=) to check from_config") from None
                raise AssertionError(f"from_config refused {what}: {exc}") from None
            except Exception as exc:  # noqa: BLE001 - what a user would meet as an AdapterError
                raise AssertionError(f"from_config raised {type(exc).__name__} on {what} (a user would get no message "
                                     f"naming a key): {exc}") from None
            assert isinstance(model, SolverAdapter), f"from_config returned {type(model).__name__}, not an adapter"
            built.append(model)
            assert model.n_dofs >= 1, f"from_config built a model with {model.n_dofs} dofs"
            return model

        try:
            first = build(table, f"the [model] table {table}")
            defaults = _documented_defaults(schema, table) if schema is not None else {}
            if defaults:
                full = {**table, **defaults}
                differs = _same_model(first, build(full, f"the table completed with its documented defaults {full}"), tol)
                assert not differs, (f"the documented defaults {defaults} are not the ones from_config applies: "
                                     f"{differs}; make Key(default=...) match the constructor")
        finally:
            for model in built:
                model.close()

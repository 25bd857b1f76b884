"""Scene files: what to compute, in TOML.

Minimum schema (every later feature extends it without breaking it)::

    [model]
    solver = "polynomial"          # an entry-point name under stepnf.solvers
    file = "system.npz"            # adapter-specific keys; relative paths are relative to the scene
    [analysis]
    master_modes = [0, 2]          # 0-based elastic-mode indices (rigid modes excluded), or labels "(2,0)"
    methods = ["nf", "dnf", "md", "smd"]
    retained_modes = 10            # modes kept in the modal sums (nf, md, smd); default 10
                                   # for FE adapters, every mode for modal models
    [output]
    dir = "results"

Optional ``[analysis]`` keys: ``qm_order`` ("full" | "modal": how md and smd
are evaluated; default "full" for FE adapters, "modal" for modal models),
``tensors`` ("targeted" | "full": the full Muravyov-Rizzi STEP over the
retained modes), ``rigid_modes`` ("auto" | int), ``rigid_tolerance``,
``degeneracy_tolerance``, ``resonance_tolerance``, ``coupling_tolerance``,
``linear_solver`` ("auto" | "dense" | "superlu" | "mumps"), ``deflation``
(true: shifted solves below the computed spectrum reuse the eigen-solver's
factorisation, see :mod:`stepnf.deflation`; false: one factorisation per
shift), ``max_modes``; and
the table ``[analysis.step]``: ``amplitude`` ("auto" | a length in model
units), ``relative_amplitude`` (fraction of the characteristic length),
``check`` (bool), ``check_ratio``, ``tolerance``, ``method`` ("forces" |
"tangent": G and h from the solver's tangent stiffness, for solvers that
offer it and print few digits). ``[output]``: ``dir``,
``name`` (file stem, default the scene's), ``hdf5`` (bool), ``plot`` (bool).
"""
from __future__ import annotations

import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from .errors import SceneError, allowed
from .evaluators import Tolerances
from .linalg import BACKENDS
from .step import STEP_METHODS, StepPolicy

METHODS = ("nf", "dnf", "md", "smd", "md_modal", "smd_modal", "md_full", "smd_full")
TOP_KEYS = ("model", "analysis", "output")
ANALYSIS_KEYS = ("master_modes", "methods", "retained_modes", "qm_order", "tensors", "rigid_modes",
                 "rigid_tolerance", "degeneracy_tolerance", "resonance_tolerance", "coupling_tolerance",
                 "linear_solver", "deflation", "max_modes", "step")
STEP_KEYS = ("amplitude", "relative_amplitude", "check", "check_ratio", "tolerance", "method")
OUTPUT_KEYS = ("dir", "name", "hdf5", "plot")
_LABEL = re.compile(r"^\s*\(\s*(\d+)\s*,\s*(\d+)\s*\)\s*$")


def parse_label(text: str) -> tuple[int, int] | None:
    """``"(2,0)"`` -> ``(2, 0)``; ``None`` when the text is not a (k, n) label."""
    m = _LABEL.match(text)
    return (int(m.group(1)), int(m.group(2))) if m else None


@dataclass
class Scene:
    """A validated scene. ``model`` holds the adapter keys (without ``solver``)."""

    solver: str
    model: dict[str, Any]
    master_modes: list[int | str]
    methods: list[str]
    retained_modes: int | None = None  # None: 10 for FE adapters, every mode of a modal model
    qm_order: str | None = None
    tensors: str = "targeted"
    rigid_modes: int | None = None
    rigid_tolerance: float = 1e-11
    degeneracy_tolerance: float = 1e-3
    tolerances: Tolerances = field(default_factory=Tolerances)
    linear_solver: str = "auto"
    deflation: bool = True
    max_modes: int = 400
    step: StepPolicy = field(default_factory=StepPolicy)
    output_dir: Path = Path("results")
    output_name: str = "stepnf"
    write_hdf5: bool = True
    plot: bool = False
    file: Path | None = None
    base_dir: Path = Path(".")
    text: str = ""

    def where(self) -> str:
        return str(self.file) if self.file else "<scene>"


def _number(file, key, value, *, positive=False, nonneg=False, integer=False, lo=None, hi=None):
    ok_type = isinstance(value, int) if integer else isinstance(value, (int, float))
    if isinstance(value, bool) or not ok_type:
        raise SceneError(file, key, f"expected {'an integer' if integer else 'a number'}, got {value!r}")
    if not math.isfinite(float(value)):
        raise SceneError(file, key, f"expected a finite number, got {value!r}")
    if positive and not value > 0:
        raise SceneError(file, key, f"must be > 0, got {value!r}")
    if nonneg and value < 0:
        raise SceneError(file, key, f"must be >= 0, got {value!r}")
    if lo is not None and value < lo or hi is not None and value > hi:
        raise SceneError(file, key, f"must lie in [{lo}, {hi}], got {value!r}")
    return value


def _choice(file, key, value, choices):
    if value not in choices:
        raise SceneError(file, key, f"got {value!r}; allowed values: {allowed(choices)}")
    return value


def _unknown(file, table: str, data: Mapping, keys) -> None:
    for k in data:
        if k not in keys:
            raise SceneError(file, f"{table}.{k}" if table else k,
                             f"unknown key; allowed keys of [{table or 'top level'}]: {allowed(keys)}")


def load_scene(path: str | Path) -> Scene:
    """Read and validate a scene file; errors name the file, the key and what is allowed."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise SceneError(path, None, f"cannot read the scene file: {exc.strerror or exc}") from exc
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(path, None, f"not valid TOML: {exc}") from exc
    return parse_scene(data, file=path.resolve(), base_dir=path.resolve().parent, text=text)


def parse_scene(data: Mapping[str, Any], *, file: Path | None = None, base_dir: Path | None = None,
                text: str = "") -> Scene:
    """Validate a scene given as a mapping (what ``tomllib`` returns)."""
    f = file
    _unknown(f, "", data, TOP_KEYS)
    model = data.get("model")
    if not isinstance(model, Mapping):
        raise SceneError(f, "model", "missing table [model] (with at least solver = \"<name>\")")
    solver = model.get("solver")
    if not isinstance(solver, str) or not solver:
        raise SceneError(f, "model.solver", "missing or not a string; give an installed solver name "
                         "(list them with `stepnf solvers`)")
    an = data.get("analysis")
    if not isinstance(an, Mapping):
        raise SceneError(f, "analysis", "missing table [analysis] (master_modes, methods, ...)")
    _unknown(f, "analysis", an, ANALYSIS_KEYS)

    masters = an.get("master_modes")
    if not isinstance(masters, list) or not masters:
        raise SceneError(f, "analysis.master_modes", "expected a non-empty list of elastic-mode indices "
                         "(0-based, rigid modes excluded) or labels such as \"(2,0)\"")
    for i, m in enumerate(masters):
        if isinstance(m, bool) or not isinstance(m, (int, str)):
            raise SceneError(f, f"analysis.master_modes[{i}]", f"expected an integer or a label, got {m!r}")
        if isinstance(m, int) and m < 0:
            raise SceneError(f, f"analysis.master_modes[{i}]", f"mode indices start at 0, got {m}")
        if isinstance(m, str) and parse_label(m) is None and (not m.strip() or m.strip().startswith("(")):
            raise SceneError(f, f"analysis.master_modes[{i}]",
                             f"{m!r} is not a label: write (k, n) labels as \"(2,0)\" (k nodal diameters, "
                             "n nodal circles), or give a 0-based mode index")
    if len(set(map(str, masters))) != len(masters):
        raise SceneError(f, "analysis.master_modes", f"repeated master modes in {masters}")

    methods = an.get("methods", ["nf", "dnf", "md", "smd"])
    if not isinstance(methods, list) or not methods:
        raise SceneError(f, "analysis.methods", f"expected a non-empty list from {allowed(METHODS)}")
    for i, m in enumerate(methods):
        _choice(f, f"analysis.methods[{i}]", m, METHODS)
    if len(set(methods)) != len(methods):
        raise SceneError(f, "analysis.methods", f"repeated methods in {methods}")

    sc = Scene(solver=solver, model={k: v for k, v in model.items() if k != "solver"},
               master_modes=list(masters), methods=list(methods), file=file,
               base_dir=base_dir or Path("."), text=text)
    if "retained_modes" in an:
        sc.retained_modes = _number(f, "analysis.retained_modes", an["retained_modes"], integer=True, lo=1)
    if "qm_order" in an:
        sc.qm_order = _choice(f, "analysis.qm_order", an["qm_order"], ("full", "modal"))
    if "tensors" in an:
        sc.tensors = _choice(f, "analysis.tensors", an["tensors"], ("targeted", "full"))
    if "rigid_modes" in an and an["rigid_modes"] != "auto":
        sc.rigid_modes = _number(f, "analysis.rigid_modes", an["rigid_modes"], integer=True, lo=0)
    for key, attr in (("rigid_tolerance", "rigid_tolerance"), ("degeneracy_tolerance", "degeneracy_tolerance")):
        if key in an:
            setattr(sc, attr, float(_number(f, f"analysis.{key}", an[key], positive=True)))
    tol = {}
    for key, attr in (("resonance_tolerance", "resonance"), ("coupling_tolerance", "coupling")):
        if key in an:
            tol[attr] = float(_number(f, f"analysis.{key}", an[key], positive=True))
    sc.tolerances = Tolerances(**tol)
    if "linear_solver" in an:
        sc.linear_solver = _choice(f, "analysis.linear_solver", an["linear_solver"], BACKENDS)
    if "deflation" in an:
        if not isinstance(an["deflation"], bool):
            raise SceneError(f, "analysis.deflation", f"expected true or false, got {an['deflation']!r}")
        sc.deflation = an["deflation"]
    if "max_modes" in an:
        sc.max_modes = _number(f, "analysis.max_modes", an["max_modes"], integer=True, lo=2)
    step = an.get("step", {})
    if not isinstance(step, Mapping):
        raise SceneError(f, "analysis.step", "expected a table [analysis.step]")
    _unknown(f, "analysis.step", step, STEP_KEYS)
    kw: dict[str, Any] = {}
    if "amplitude" in step and step["amplitude"] != "auto":
        kw["amplitude"] = float(_number(f, "analysis.step.amplitude", step["amplitude"], positive=True))
    if "relative_amplitude" in step:
        kw["relative_amplitude"] = float(_number(f, "analysis.step.relative_amplitude",
                                                 step["relative_amplitude"], positive=True))
    if "check" in step:
        if not isinstance(step["check"], bool):
            raise SceneError(f, "analysis.step.check", f"expected true or false, got {step['check']!r}")
        kw["check"] = step["check"]
    if "check_ratio" in step:
        r = float(_number(f, "analysis.step.check_ratio", step["check_ratio"], positive=True))
        if r == 1.0:
            raise SceneError(f, "analysis.step.check_ratio", "must differ from 1 (the check needs a second amplitude)")
        kw["check_ratio"] = r
    if "tolerance" in step:
        kw["tolerance"] = float(_number(f, "analysis.step.tolerance", step["tolerance"], positive=True))
    if "method" in step:
        kw["method"] = _choice(f, "analysis.step.method", step["method"], STEP_METHODS)
    sc.step = StepPolicy(**kw)

    out = data.get("output", {})
    if not isinstance(out, Mapping):
        raise SceneError(f, "output", "expected a table [output]")
    _unknown(f, "output", out, OUTPUT_KEYS)
    d = out.get("dir", "results")
    if not isinstance(d, str) or not d:
        raise SceneError(f, "output.dir", f"expected a folder path, got {d!r}")
    sc.output_dir = Path(d) if Path(d).is_absolute() else sc.base_dir / d
    name = out.get("name", file.stem if file else "stepnf")
    if not isinstance(name, str) or not name or "/" in name:
        raise SceneError(f, "output.name", f"expected a file stem without '/', got {name!r}")
    sc.output_name = name
    for key, attr in (("hdf5", "write_hdf5"), ("plot", "plot")):
        if key in out:
            if not isinstance(out[key], bool):
                raise SceneError(f, f"output.{key}", f"expected true or false, got {out[key]!r}")
            setattr(sc, attr, out[key])
    return sc

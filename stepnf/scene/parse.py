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
retained modes), ``rigid_modes`` ("auto": the null vectors of K among the
eigenvalues below ``rigid_tolerance`` x the largest, :mod:`stepnf.linalg.null_space`; or an int),
``rigid_tolerance``,
``degeneracy_tolerance``, ``resonance_tolerance``, ``coupling_tolerance``,
``linear_solver`` ("auto" | "dense" | "superlu" | "mumps"), ``deflation``
(true: shifted solves below the computed spectrum reuse the eigen-solver's
factorisation, see :mod:`stepnf.linalg.deflation`; false: one factorisation per
shift), ``max_modes``, ``thickness`` (a length h in model units) and
``transverse`` ("ux" | "uy" | "uz" | a direction vector): with them Gamma =
T (h / max|phi . e|)^2 is reported for any structure (:mod:`stepnf.nf.gamma`);
and
the table ``[analysis.step]``: ``amplitude`` ("auto" | a length in model
units), ``relative_amplitude`` (fraction of the characteristic length),
``check`` (bool), ``check_ratio``, ``tolerance``, ``method`` ("forces" |
"tangent": G and h from the solver's tangent stiffness, for solvers that
offer it and print few digits); the table ``[analysis.backbone]`` (the DPIM
backbone of every master mode, :mod:`stepnf.keys.backbone`); the tables ``[analysis.damping]`` and
``[analysis.forcing]`` (the forced responses of the masters, :mod:`stepnf.keys.forced`). ``[output]``: ``dir``,
``name`` (file stem, default the scene's), ``hdf5`` (bool), ``plot`` (bool),
``fields`` (bool, default true: beside the results file ``NAME.h5``, the mesh
with each master mode's shape and second-order fields for ParaView,
``NAME_fields.xdmf``/``.h5``/``.vtu``, where the adapter gives an output mesh;
:mod:`stepnf.io.fields`).

Every key is checked when the file is read, with its allowed range (the
constants below give each range and its reason): a wrong type, a value out of
range or a file that is not UTF-8 TOML is a :class:`~stepnf.errors.SceneError`
naming the file and the key (exit code 2), worded by the checks of
:mod:`stepnf.keys.checks`. ``[model]`` is checked too, by the solver's own
declared keys (:func:`check_model_keys`; ``stepnf solvers --keys NAME`` lists
them), so a misspelt key anywhere fails when the scene is read.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from stepnf.keys.backbone import BackboneSpec, parse_backbone
from stepnf.keys.forced import check_forced_scene, parse_damping, parse_forcing
from stepnf.keys.checks import (check_bool, check_choice, check_name, check_number, check_table, check_text, check_unknown,
                     describe_value, read_toml)
from stepnf.errors import SceneError, UnknownSolverError, allowed
from stepnf.forced.spec import DampingSpec, ForcingSpec, LoadSpec
from stepnf.nf.evaluators import Tolerances
from stepnf.linalg.factorization import BACKENDS
from stepnf.methods import DEFAULT_METHODS, NAMES, ORDERS
from stepnf.step.procedure import STEP_METHODS, StepPolicy

#: The names ``analysis.methods`` allows (:data:`stepnf.methods.TABLE`).
METHODS = NAMES
TOP_KEYS = ("model", "analysis", "output")
ANALYSIS_KEYS = ("master_modes", "methods", "retained_modes", "qm_order", "tensors", "rigid_modes",
                 "rigid_tolerance", "degeneracy_tolerance", "resonance_tolerance", "coupling_tolerance",
                 "linear_solver", "deflation", "max_modes", "thickness", "transverse", "step", "backbone",
                 "damping", "forcing")
STEP_KEYS = ("amplitude", "relative_amplitude", "check", "check_ratio", "tolerance", "method")
OUTPUT_KEYS = ("dir", "name", "hdf5", "plot", "fields")
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
    thickness: float | None = None  # h of Gamma (model length units); None: the model's own, if any
    transverse: str | tuple[float, float, float] | None = None  # "ux"/"uy"/"uz" or a unit vector
    step: StepPolicy = field(default_factory=StepPolicy)
    backbone: BackboneSpec | None = None  # [analysis.backbone]: the DPIM backbone (None: not computed)
    damping: DampingSpec | None = None  # [analysis.damping]: of the forced responses (stepnf.keys.forced)
    forcing: ForcingSpec | None = None  # [analysis.forcing]: the forced responses (None: not computed)
    output_dir: Path = Path("results")
    output_name: str = "stepnf"
    write_hdf5: bool = True
    plot: bool = False
    fields: bool = True  # [output] fields: ParaView files beside the results file (stepnf.io.fields)
    file: Path | None = None
    base_dir: Path = Path(".")
    text: str = ""
    #: The user's permission for programs the scene names (:mod:`stepnf.runtime.programs`): never read from the
    #: scene, given to :func:`load_scene`; ``None``: the permission in force (flag, environment).
    allow_programs: bool | None = None

    def where(self) -> str:
        return str(self.file) if self.file else "<scene>"


#: Ranges of the [analysis] numbers (reasons in the comments; the tolerances are relative, so above 1
#: they can only be nonsense).
MAX_MODES = 100_000        # eigenpairs: beyond this no FE eigensolver finishes in memory
MAX_MODE_INDEX = MAX_MODES - 1
MAX_LABEL = 1_000          # nodal diameters / circles of a (k, n) label
MAX_MASTERS = 1_000        # master modes of one scene (each costs STEP evaluations)
MAX_RIGID_MODES = 1_000    # a body has 6; 1000 allows many unconnected parts
#: A STEP amplitude is a displacement in model length units: 1e-15 .. 1e15 covers nanometres in
#: metres and kilometres in micrometres, and keeps q^3 (the cubic term) far inside float range.
AMPLITUDE_RANGE = (1e-15, 1e15)
#: relative_amplitude is a fraction of the characteristic length (a shell's thickness): below 1e-6
#: the cubic part of f is lost in round-off (1e-12 of the linear part); above 100 thicknesses the
#: field is no deformation a thin structure carries.
RELATIVE_AMPLITUDE_RANGE = (1e-6, 100.0)
#: check_ratio scales the second STEP amplitude; outside [1e-3, 1e3] the check measures round-off.
CHECK_RATIO_RANGE = (1e-3, 1e3)
#: analysis.thickness: a length, in the range of every geometry length (:mod:`stepnf.geometry.keys`).
THICKNESS_RANGE = (1e-12, 1e12)
#: analysis.transverse by name: the translations of :data:`stepnf.plugin.adapter.DIRECTIONS`.
TRANSVERSE_NAMES = ("ux", "uy", "uz")


def load_scene(path: str | Path, *, allow_programs: bool | None = None) -> Scene:
    """Read and validate a scene file; errors name the file, the key and what is allowed.

    ``allow_programs``: the user's permission for the programs a scene names (``executable``,
    ``command``, ``templates``; :mod:`stepnf.runtime.programs`), kept on the scene for every model built from it;
    ``None``: the permission in force (``--allow-programs``, ``STEPNF_ALLOW_PROGRAMS``)."""
    path = Path(path)
    data, text = read_toml(path, "scene")
    return parse_scene(data, file=path.resolve(), base_dir=path.resolve().parent, text=text,
                       allow_programs=allow_programs)


def parse_scene(data: Mapping[str, Any], *, file: Path | None = None, base_dir: Path | None = None,
                text: str = "", check_model: bool = True, allow_programs: bool | None = None) -> Scene:
    """Validate a scene given as a mapping (what ``tomllib`` returns).

    ``check_model``: also check ``[model]`` against the solver's declared keys (the solver must be
    installed; see :func:`check_model_keys`), as every scene read from a file is. ``allow_programs``: as
    for :func:`load_scene`.
    """
    f = file
    if not isinstance(data, Mapping):
        raise SceneError(f, None, f"expected a TOML document (a table), got {describe_value(data)}")
    if "sweep" in data:
        raise SceneError(f, "sweep", "this is a sweep file, not a scene: run it with `stepnf sweep FILE`")
    check_unknown(f, "", data, TOP_KEYS)
    model = data.get("model")
    if not isinstance(model, Mapping):
        raise SceneError(f, "model", "missing table [model] (with at least solver = \"<name>\")" if model is None
                         else f"expected a table [model], got {describe_value(model)}")
    solver = model.get("solver")
    if not isinstance(solver, str) or not solver.strip():
        raise SceneError(f, "model.solver", f"missing or not a string (got {describe_value(solver)}); give an "
                         "installed solver name (list them with `stepnf solvers`)")
    an = data.get("analysis")
    if not isinstance(an, Mapping):
        raise SceneError(f, "analysis", "missing table [analysis] (master_modes, methods, ...)" if an is None
                         else f"expected a table [analysis], got {describe_value(an)}")
    check_unknown(f, "analysis", an, ANALYSIS_KEYS)
    sc = Scene(solver=solver, model={k: v for k, v in model.items() if k != "solver"},
               master_modes=_masters(f, an.get("master_modes")),
               methods=_methods(f, an.get("methods", list(DEFAULT_METHODS))), file=file,
               base_dir=base_dir or Path("."), text=text, allow_programs=allow_programs)
    _analysis(f, an, sc)
    sc.step = _step(f, an.get("step", {}))
    sc.backbone = parse_backbone(f, an["backbone"]) if "backbone" in an else None
    _forced(f, an, sc)
    _output(f, data.get("output", {}), sc)
    if check_model:
        check_model_keys(sc)
    return sc


def _forced(f, an: Mapping[str, Any], sc: Scene) -> None:
    """``[analysis.damping]`` and ``[analysis.forcing]`` (:mod:`stepnf.keys.forced`): the forced responses."""
    from stepnf.plugin.adapter import DIRECTIONS

    if "damping" in an:
        sc.damping = DampingSpec(**parse_damping(f, an["damping"], len(sc.master_modes)))
    if "forcing" in an:
        got = parse_forcing(f, an["forcing"], DIRECTIONS)
        load = LoadSpec(**got["load"]) if got["load"] is not None else None
        sc.forcing = ForcingSpec(got["modal"], load, got["frequency_range"], got["points"])
    check_forced_scene(f, an, sc.backbone is not None)


def check_model_keys(scene: Scene) -> dict[str, Any]:
    """The scene's ``[model]`` keys checked by its solver's
    :meth:`~stepnf.keys.schema.FromScene.validate_config` (pure: nothing is built or computed), so a
    misspelt key fails when the scene is read, before any eigen-solve or Dask worker."""
    from stepnf.runtime.programs import allow_programs
    from stepnf.plugin.registry import get_solver

    try:
        cls = get_solver(scene.solver)
    except UnknownSolverError as exc:
        raise SceneError(scene.file, "model.solver", str(exc)) from exc
    with allow_programs(scene.allow_programs):
        return cls.validate_config(scene.model, base_dir=scene.base_dir, scene_file=scene.file)


def _masters(f, masters: Any) -> list[int | str]:
    """``analysis.master_modes``: 0-based indices or ``"(k,n)"`` labels, no repeats."""
    key = "analysis.master_modes"
    if not isinstance(masters, list) or not masters or len(masters) > MAX_MASTERS:
        raise SceneError(f, key, f"expected a non-empty list (at most {MAX_MASTERS}) of elastic-mode indices "
                         f"(0-based, rigid modes excluded) or labels such as \"(2,0)\", got {describe_value(masters)}")
    for i, m in enumerate(masters):
        if isinstance(m, bool) or not isinstance(m, (int, str)):
            raise SceneError(f, f"{key}[{i}]", f"expected an integer or a label, got {describe_value(m)}")
        if isinstance(m, int):
            check_number(f, f"{key}[{i}]", m, integer=True, lo=0, hi=MAX_MODE_INDEX,
                         why=" (mode indices start at 0, rigid modes excluded)")
        else:
            _label(f, f"{key}[{i}]", m)
    if len(set(map(str, masters))) != len(masters):
        raise SceneError(f, key, f"repeated master modes in {masters}")
    return list(masters)


def _label(f, key: str, m: str) -> None:
    """A master mode given as text: a ``(k, n)`` label with k, n <= :data:`MAX_LABEL`, or an adapter's name."""
    lab = parse_label(m)
    if lab is None and (not m.strip() or m.strip().startswith("(") or len(m) > 200):
        raise SceneError(f, key, f"{describe_value(m)} is not a label: write (k, n) labels as \"(2,0)\" "
                         "(k nodal diameters, n nodal circles), or give a 0-based mode index")
    if lab is not None and max(lab) > MAX_LABEL:
        raise SceneError(f, key, f"label {m!r}: k and n must lie in [0, {MAX_LABEL}]")


def _methods(f, methods: Any) -> list[str]:
    key = "analysis.methods"
    if not isinstance(methods, list) or not methods:
        raise SceneError(f, key, f"expected a non-empty list from {allowed(METHODS)}, got {describe_value(methods)}")
    for i, m in enumerate(methods):
        check_choice(f, f"{key}[{i}]", m, METHODS)
    if len(set(methods)) != len(methods):
        raise SceneError(f, key, f"repeated methods in {methods}")
    return list(methods)


#: Relative tolerances of [analysis]: (scene key, Scene attribute or Tolerances field, upper bound).
#: rigid_tolerance compares |w^2| with the eigenvalue scale: at 1 every mode would be rigid.
_TOLERANCES = (("rigid_tolerance", "rigid_tolerance", 1.0), ("degeneracy_tolerance", "degeneracy_tolerance", 1.0),
               ("resonance_tolerance", "resonance", 1.0), ("coupling_tolerance", "coupling", 1.0))


def _analysis(f, an: Mapping[str, Any], sc: Scene) -> None:
    """The optional scalar keys of ``[analysis]`` (everything but master_modes, methods, step)."""
    if "retained_modes" in an:
        sc.retained_modes = check_number(f, "analysis.retained_modes", an["retained_modes"], integer=True,
                                         lo=1, hi=MAX_MODES)
    if "qm_order" in an:
        sc.qm_order = check_choice(f, "analysis.qm_order", an["qm_order"], ORDERS)
    if "tensors" in an:
        sc.tensors = check_choice(f, "analysis.tensors", an["tensors"], ("targeted", "full"))
    if "rigid_modes" in an and an["rigid_modes"] != "auto":
        sc.rigid_modes = check_number(f, "analysis.rigid_modes", an["rigid_modes"], integer=True, lo=0,
                                      hi=MAX_RIGID_MODES, why=' (or "auto")')
    tol = {}
    for key, attr, hi in _TOLERANCES:
        if key in an:
            v = float(check_number(f, f"analysis.{key}", an[key], lo=0, hi=hi, lo_open=True,
                                   why=" (a relative tolerance)"))
            if hasattr(sc, attr):
                setattr(sc, attr, v)
            else:
                tol[attr] = v
    sc.tolerances = Tolerances(**tol)
    if "linear_solver" in an:
        sc.linear_solver = check_choice(f, "analysis.linear_solver", an["linear_solver"], BACKENDS)
    if "deflation" in an:
        sc.deflation = check_bool(f, "analysis.deflation", an["deflation"])
    if "max_modes" in an:
        sc.max_modes = check_number(f, "analysis.max_modes", an["max_modes"], integer=True, lo=2, hi=MAX_MODES)
    if "thickness" in an:
        lo, hi = THICKNESS_RANGE
        sc.thickness = float(check_number(f, "analysis.thickness", an["thickness"], lo=lo, hi=hi,
                                          why=" (the thickness h of Gamma, a length in model units)"))
    if "transverse" in an:
        sc.transverse = _transverse(f, an["transverse"])


def _transverse(f, value: Any) -> str | tuple[float, float, float]:
    """``analysis.transverse``: a translation name, or a nonzero direction vector (normalised)."""
    key = "analysis.transverse"
    if isinstance(value, str):
        return check_choice(f, key, value, TRANSVERSE_NAMES, why=" (or a direction vector [ex, ey, ez])")
    if not isinstance(value, list) or len(value) != 3:
        raise SceneError(f, key, f"expected one of {allowed(TRANSVERSE_NAMES)} or a direction vector [ex, ey, ez], "
                         f"got {describe_value(value)}")
    e = [float(check_number(f, f"{key}[{i}]", v, lo=-1e12, hi=1e12)) for i, v in enumerate(value)]
    norm = math.hypot(*e)  # no underflow: [1e-300, 0, 0] is a direction too
    if not norm > 0:
        raise SceneError(f, key, "the direction vector must not be zero")
    return (e[0] / norm, e[1] / norm, e[2] / norm)


def _step(f, step: Any) -> StepPolicy:
    """``[analysis.step]``: the STEP amplitude policy."""
    check_table(f, "analysis.step", step)
    check_unknown(f, "analysis.step", step, STEP_KEYS)
    kw: dict[str, Any] = {}
    if "amplitude" in step and step["amplitude"] != "auto":
        lo, hi = AMPLITUDE_RANGE
        kw["amplitude"] = float(check_number(f, "analysis.step.amplitude", step["amplitude"], lo=lo, hi=hi,
                                             why=' (a length in model units, or "auto")'))
    if "relative_amplitude" in step:
        lo, hi = RELATIVE_AMPLITUDE_RANGE
        kw["relative_amplitude"] = float(check_number(f, "analysis.step.relative_amplitude",
                                                      step["relative_amplitude"], lo=lo, hi=hi,
                                                      why=" (a fraction of the characteristic length)"))
    if "check" in step:
        kw["check"] = check_bool(f, "analysis.step.check", step["check"])
    if "check_ratio" in step:
        lo, hi = CHECK_RATIO_RANGE
        r = float(check_number(f, "analysis.step.check_ratio", step["check_ratio"], lo=lo, hi=hi))
        if r == 1.0:
            raise SceneError(f, "analysis.step.check_ratio", "must differ from 1 (the check needs a second amplitude)")
        kw["check_ratio"] = r
    if "tolerance" in step:
        kw["tolerance"] = float(check_number(f, "analysis.step.tolerance", step["tolerance"], lo=0, hi=1.0,
                                             lo_open=True, why=" (a relative error)"))
    if "method" in step:
        kw["method"] = check_choice(f, "analysis.step.method", step["method"], STEP_METHODS)
    return StepPolicy(**kw)


def _output(f, out: Any, sc: Scene) -> None:
    """``[output]``: folder, file stem, what to write."""
    check_table(f, "output", out)
    check_unknown(f, "output", out, OUTPUT_KEYS)
    d = check_text(f, "output.dir", out.get("dir", "results"), "a folder path")
    sc.output_dir = Path(d) if Path(d).is_absolute() else sc.base_dir / d
    # the default, the scene's own file stem, has no '/' and stays inside the folder
    sc.output_name = check_name(f, "output.name", out["name"]) if "name" in out else (f.stem if f else "stepnf")
    for key, attr in (("hdf5", "write_hdf5"), ("plot", "plot"), ("fields", "fields")):
        if key in out:
            setattr(sc, attr, check_bool(f, f"output.{key}", out[key]))

"""Results of a run: per-mode records, the JSON document and the HDF5 file.

The JSON document (``stepnf run --json``) holds at least ``modes`` (each with
``index``, ``label``, ``omega``, ``rho`` and ``methods``: ``nf``/``dnf``/``md``/
``smd`` -> ``{T, C, flags, ...}``) and ``counts`` (``force_evaluations``,
``linear_solves``, ``factorizations``), ``timings`` (stage -> seconds) and
``memory`` (stage -> peak and current resident MiB at its end); with ``[analysis.backbone]`` a mode has its
``backbone`` block, with ``[analysis.forcing]`` its ``frc`` list (one entry per forcing level; empty with a
``frc_reason`` when the master has none). The HDF5 file (root attributes
``format = "stepnf-run"``, ``format_version = 1``) is built in memory and
written by :mod:`stepnf.io.atomic`, so a crash or a full disk never leaves a
half-written file and never destroys the previous one.
"""
from __future__ import annotations

import json
import platform
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from stepnf.io import atomic
from stepnf.nf.coefficient import MethodResult, json_float
from stepnf.errors import StoreError
from stepnf.flags import json_safe, t_unusable


@dataclass
class ModeResult:
    """One master mode: index among the elastic modes, label, frequency, slow/fast ratio, methods."""

    index: int
    label: Any
    omega: float
    rho: float | None
    rho_mode: int | None = None
    omega_bar: float | None = None
    w_max: float | None = None
    methods: dict[str, MethodResult] = field(default_factory=dict)
    step: dict[str, Any] = field(default_factory=dict)
    flags: list[dict] = field(default_factory=list)
    #: ``[analysis.backbone]``: the JSON block of :func:`stepnf.dpim.backbone_report.backbone_report` (None: not asked)
    backbone: dict[str, Any] | None = None
    #: ``[analysis] transverse``: the share of the mode's kinetic energy in that direction (:mod:`stepnf.nf.gamma`)
    transverse_share: float | None = None
    #: ``[analysis.forcing]``: one dict per forcing level (:meth:`stepnf.forced.frc.FRC.to_json`; None: not asked),
    #: or an empty list and ``frc_reason`` (why the master has none: no usable backbone)
    frc: list[dict[str, Any]] | None = None
    frc_reason: str | None = None

    def to_dict(self) -> dict[str, Any]:
        out = {
            "index": self.index,
            "label": label_json(self.label),
            "omega": json_float(self.omega),
            "omega_bar": json_float(self.omega_bar),
            "rho": json_float(self.rho),
            "rho_mode": self.rho_mode,
            "w_max": json_float(self.w_max),
            "transverse_share": json_float(self.transverse_share),
            "step": {k: json_float(v) if isinstance(v, float) else v for k, v in self.step.items()},
            "flags": json_safe(self.flags),
            "methods": {k: v.to_dict() for k, v in self.methods.items()},
        }
        if self.backbone is not None:
            out["backbone"] = json_safe(self.backbone)
        if self.frc is not None:
            out["frc"] = json_safe(self.frc)
            if self.frc_reason is not None:
                out["frc_reason"] = self.frc_reason
        return out


def label_json(label: Any) -> Any:
    """Labels as JSON: (k, n) tuples become [k, n]; strings stay; None is null."""
    if label is None:
        return None
    if isinstance(label, (tuple, list)):
        return [int(x) if isinstance(x, (int, np.integer)) else x for x in label]
    return str(label)


def label_text(label: Any) -> str:
    if label is None:
        return "-"
    if isinstance(label, (tuple, list)):
        return "(" + ",".join(str(x) for x in label) + ")"
    return str(label)


@dataclass
class RunResult:
    """Everything a run produced."""

    scene: dict[str, Any]
    modes: list[ModeResult]
    counts: dict[str, int]
    timings: dict[str, float]
    spectrum: dict[str, Any]
    model: dict[str, Any] = field(default_factory=dict)
    kappa: float | None = None
    flags: list[dict] = field(default_factory=list)
    arrays: dict[str, np.ndarray] = field(default_factory=dict)
    hdf5_path: str | None = None
    extra_files: list[str] = field(default_factory=list)
    counters_note: str | None = None
    #: the adapter's mesh for the field files (:mod:`stepnf.io.fields`), until they are written; not stored
    output_mesh: Any = field(default=None, repr=False)
    #: ``[analysis.backbone]``: master index -> its :class:`stepnf.dpim.parametrisation.DPIMResult` (to rebuild x(theta) at an
    #: amplitude); not stored: the JSON block, the HDF5 arrays ``backbone_<p>_*`` hold what is kept
    backbones: dict[int, Any] = field(default_factory=dict, repr=False)
    #: stage key -> ``{"peak_rss_mb", "rss_mb"}`` at the stage's end (MiB; this process, or this MPI rank:
    #: rank 0's in the stored file), plus ``"total"`` at the run's end (:func:`stepnf.runtime.progress.memory_now`)
    memory: dict[str, dict[str, float | None]] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {
            "stepnf_version": versions()["stepnf"],
            "scene": self.scene,
            "model": self.model,
            "kappa": json_float(self.kappa),
            "modes": [m.to_dict() for m in self.modes],
            "counts": self.counts,
            "timings": {k: round(v, 6) for k, v in self.timings.items()},
            "memory": self.memory,
            "spectrum": self.spectrum,
            "flags": json_safe(self.flags),
            "hdf5": self.hdf5_path,
            "files": self.extra_files,
        }

    def to_json(self, **kw: Any) -> str:
        return json.dumps(self.to_dict(), allow_nan=False, **kw)

    def failed_backbones(self) -> list[tuple[int, str]]:
        """``(master index, reason)`` of every backbone whose DPIM failed (its block's ``failed``): the run kept
        everything else, and ``stepnf run`` exits 3 after printing it."""
        return [(m.index, str(m.backbone.get("failed_reason", ""))) for m in self.modes
                if m.backbone and m.backbone.get("failed")]


def versions() -> dict[str, str]:
    """Versions of stepnf and its numerical stack (stored with every result)."""
    import h5py
    import scipy

    from stepnf import __version__

    return {"stepnf": __version__, "python": platform.python_version(), "numpy": np.__version__,
            "scipy": scipy.__version__, "h5py": h5py.__version__, "platform": platform.platform()}


RUN_FORMAT = "stepnf-run"
RUN_FORMAT_VERSION = 1


def write_hdf5(result: RunResult, path: str | Path, scene_text: str = "") -> Path:
    """Write the run atomically (built in memory, then :func:`stepnf.io.atomic.write_bytes`).

    Raises :class:`stepnf.errors.OutputError` (naming the file and the reason) if it cannot be
    written; the previous file, if any, is then untouched and no temporary file is left.
    """
    def fill(f: Any) -> None:
        f.attrs["versions"] = json.dumps(versions())
        f.attrs["json"] = result.to_json()
        inp = f.create_group("inputs")
        inp.attrs["scene_text"] = scene_text
        inp.attrs["scene"] = json.dumps(result.scene, default=str)
        inp.attrs["model"] = json.dumps(result.model, default=str)
        f.create_group("counts").attrs.update({k: int(v) for k, v in result.counts.items()})
        f.create_group("timings").attrs.update({k: float(v) for k, v in result.timings.items()})
        sp = f.create_group("spectrum")
        sp["omega"] = np.asarray(result.spectrum.get("omega", []), dtype=float)
        sp.attrs["labels"] = json.dumps([label_json(x) for x in result.spectrum.get("labels", [])])
        sp.attrs["n_rigid"] = int(result.spectrum.get("n_rigid", 0))
        sp.attrs["degenerate_groups"] = json.dumps(result.spectrum.get("degenerate_groups", []))
        modes = f.create_group("modes")
        for m in result.modes:
            g = modes.create_group(f"mode_{m.index}")
            g.attrs["index"] = m.index
            g.attrs["label"] = json.dumps(label_json(m.label))
            g.attrs["omega"] = m.omega
            if m.rho is not None and np.isfinite(m.rho):
                g.attrs["rho"] = m.rho
            for meth, r in m.methods.items():
                mg = g.create_group(meth)
                mg["C"] = np.asarray(r.C, dtype=float)
                mg.attrs["T"] = r.T
                mg.attrs["order"] = r.order
                if r.gamma is not None:
                    mg.attrs["gamma"] = r.gamma
                if r.T_error is not None:
                    mg.attrs["T_error"] = r.T_error
                mg.attrs["flags"] = json.dumps(json_safe(r.flags), allow_nan=False)
                verdict = t_unusable(r)  # the table's n/a, recorded (the number is kept); absent in old files
                if verdict is not None:
                    mg.attrs["na_kind"], mg.attrs["na_reason"] = verdict
            if m.backbone is not None:
                g.attrs["backbone"] = json.dumps(json_safe(m.backbone), allow_nan=False)
                if m.backbone.get("failed"):  # (also in the block) the DPIM of this master failed: why
                    g.attrs["backbone_failed"] = str(m.backbone.get("failed_reason", ""))
            if m.frc is not None:  # the forced responses (their curves also in arrays frc_<p>_<i>_*)
                g.attrs["frc"] = json.dumps(json_safe(m.frc), allow_nan=False)
                if m.frc_reason is not None:
                    g.attrs["frc_reason"] = m.frc_reason
        arr = f.create_group("arrays")
        for k, v in result.arrays.items():
            arr.create_dataset(k, data=np.asarray(v), compression="gzip" if np.asarray(v).size > 1000 else None)

    return atomic.write_hdf5(path, fill, format=RUN_FORMAT, format_version=RUN_FORMAT_VERSION,
                             what="results file")


def read_hdf5(path: str | Path) -> dict[str, Any]:
    """The JSON document stored in a run's HDF5 file (plus its arrays under ``"arrays"``)."""
    import h5py

    path = Path(path)
    try:
        with h5py.File(path, "r") as f:
            atomic.check_format(f.attrs, path, format=RUN_FORMAT, version=RUN_FORMAT_VERSION,
                                what="run file")
            doc = json.loads(f.attrs["json"])
            if not isinstance(doc, dict):
                raise TypeError(f"its json attribute holds a {type(doc).__name__}, not a run document")
            doc["arrays"] = {k: np.asarray(v) for k, v in f["arrays"].items()}
    except (OSError, KeyError) as exc:
        raise StoreError(f"{path}: cannot read the HDF5 file (corrupt or truncated?): {exc}") from exc
    except (ValueError, TypeError, AttributeError, RecursionError) as exc:  # JSONDecodeError is a ValueError
        raise StoreError(f"{path}: the stored run document is malformed ({type(exc).__name__}: {exc})") from exc
    return doc

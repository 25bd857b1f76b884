"""The curves' data files, each written atomically: HDF5 (format ``"stepnf-curves"``, version 1) and CSV."""
from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from stepnf.io.atomic import csv_text, write_text
from stepnf.report.curves.data import FLAG_BITS, GAP_MASK, METHODS, Curves, CurvesError

CURVES_FORMAT = "stepnf-curves"
CURVES_FORMAT_VERSION = 1


def _mode_key(kn: tuple[int, int]) -> str:
    return f"{kn[0]}_{kn[1]}"


def _meta(curves: Curves) -> dict[str, Any]:
    opt = asdict(curves.options)
    opt["modes"] = [list(m) for m in curves.options.modes]
    return {"options": opt, "model": curves.model, "flag_bits": FLAG_BITS, "gap_mask": GAP_MASK,
            "seconds": curves.seconds,
            "conventions": "modes normalised by int phi^2 dS = 1 over the unit disk; omega nondimensional; "
                           "w_NL = w_p (1 + T a^2); gamma = T / max|phi|^2; NF over all modes of the model"}


def write_hdf5(curves: Curves, path: str | Path) -> Path:
    """Store everything: ``/kappa``, ``/frequencies/{omega,labels}``, ``/modes/<k>_<n>/...``.

    Per mode: ``omega``, ``w_max``, ``rho``, ``rho_mode``, ``T_cubic``, ``T_<m>``, ``gamma_<m>``,
    ``flags_<m>`` (bits: root attribute ``flag_bits``), ``gap_<m>``, ``notes_<m>`` for m in nf, md, smd.
    Flagged values are stored as computed (``+-inf`` included). Root attributes ``format =
    "stepnf-curves"``, ``format_version = 1`` (files of earlier stepnf say ``"stepnf-curves-1"``).
    Built in memory and written atomically (:mod:`stepnf.io.atomic`): a full disk raises
    :class:`stepnf.errors.OutputError` and leaves a previous file untouched.
    """
    import h5py

    from stepnf.io.atomic import write_hdf5 as write_atomic

    st = h5py.string_dtype()

    def fill(f: Any) -> None:
        f.attrs["meta"] = json.dumps(_meta(curves), default=str)
        f.attrs["flag_bits"] = json.dumps(FLAG_BITS)
        f.create_dataset("kappa", data=curves.kappa)
        fr = f.create_group("frequencies")
        fr.create_dataset("omega", data=curves.frequencies)
        fr.create_dataset("labels", data=np.asarray(curves.freq_labels, dtype=np.int64).reshape(-1, 2))
        modes = f.create_group("modes")
        for i, kn in enumerate(curves.modes):
            grp = modes.create_group(_mode_key(kn))
            grp.attrs["label"] = list(kn)
            for key in ("omega", "w_max", "rho", "T_cubic"):
                grp.create_dataset(key, data=getattr(curves, key)[i])
            grp.create_dataset("rho_mode", data=np.asarray(curves.rho_mode[i], dtype=object), dtype=st)
            for m in METHODS:
                grp.create_dataset(f"T_{m}", data=curves.T[m][i])
                grp.create_dataset(f"gamma_{m}", data=curves.gamma[m][i])
                grp.create_dataset(f"flags_{m}", data=curves.flags[m][i])
                grp.create_dataset(f"gap_{m}", data=curves.gaps(m)[i])
                grp.create_dataset(f"notes_{m}", data=np.asarray(curves.notes[m][i], dtype=object), dtype=st)
    return write_atomic(path, fill, format=CURVES_FORMAT, format_version=CURVES_FORMAT_VERSION,
                        what="curves file")


def read_hdf5(path: str | Path) -> dict[str, Any]:
    """Plain dict of a file written by :func:`write_hdf5` (``modes`` keyed by ``(k, n)``)."""
    import h5py

    from stepnf.io.atomic import check_format

    out: dict[str, Any] = {}
    with h5py.File(path, "r") as f:
        check_format(f.attrs, path, format=CURVES_FORMAT, version=CURVES_FORMAT_VERSION, what="curves file",
                     legacy=("stepnf-curves-1",), foreign_error=CurvesError)
        out["meta"] = json.loads(f.attrs["meta"])
        out["kappa"] = f["kappa"][()]
        out["frequencies"] = {"omega": f["frequencies/omega"][()],
                              "labels": [tuple(int(v) for v in r) for r in f["frequencies/labels"][()]]}
        out["modes"] = {}
        for grp in f["modes"].values():
            d = {}
            for key, ds in grp.items():
                v = ds[()]
                if ds.dtype.kind in "OS":
                    v = np.array([x.decode() if isinstance(x, bytes) else x for x in v], dtype=object)
                d[key] = v
            out["modes"][tuple(int(v) for v in grp.attrs["label"])] = d
    return out


def write_csv(curves: Curves, directory: str | Path) -> tuple[Path, Path]:
    """``curves.csv`` (one row per kappa and mode) and ``frequencies.csv`` (one column per label)."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    p1, p2 = d / "curves.csv", d / "frequencies.csv"
    cols = (["kappa", "mode", "omega", "w_max", "rho", "rho_mode", "T_cubic"]
            + [f"T_{m}" for m in METHODS] + [f"gamma_{m}" for m in METHODS]
            + [f"flags_{m}" for m in METHODS] + [f"gap_{m}" for m in METHODS] + [f"notes_{m}" for m in METHODS])
    rows: list[list[Any]] = [cols]
    for i, kn in enumerate(curves.modes):
        gaps = {m: curves.gaps(m)[i] for m in METHODS}
        for j, kappa in enumerate(curves.kappa):
            rows.append([repr(float(kappa)), f"({kn[0]},{kn[1]})", repr(float(curves.omega[i, j])),
                         repr(float(curves.w_max[i, j])), repr(float(curves.rho[i, j])), curves.rho_mode[i, j],
                         repr(float(curves.T_cubic[i, j]))]
                        + [repr(float(curves.T[m][i, j])) for m in METHODS]
                        + [repr(float(curves.gamma[m][i, j])) for m in METHODS]
                        + [int(curves.flags[m][i, j]) for m in METHODS]
                        + [int(gaps[m][j]) for m in METHODS] + [curves.notes[m][i, j] for m in METHODS])
    write_text(p1, csv_text(rows), what="curves table")
    freq = [["kappa"] + [f"({k},{n})" for k, n in curves.freq_labels]]
    freq += [[repr(float(kappa))] + [repr(float(v)) for v in curves.frequencies[:, j]]
             for j, kappa in enumerate(curves.kappa)]
    write_text(p2, csv_text(freq), what="frequency table")
    return p1, p2

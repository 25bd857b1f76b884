"""Small polynomial scenes written by several tests, and ``stepnf verify`` run in-process."""
from __future__ import annotations

from pathlib import Path

from stepnf.cli.main import main
from stepnf_polynomial.adapter import save_system

from helpers.systems import random_system, two_dof

#: the scene of :func:`helpers.systems.two_dof` (file ``two_dof.npz``), master mode 0; ``{backbone}`` is its
#: ``[analysis.backbone]`` table or nothing
TWO_DOF_SCENE = """[model]
solver = "polynomial"
file = "two_dof.npz"

[analysis]
master_modes = [0]
methods = ["dnf"]
{backbone}
[output]
dir = "results"
"""
TWO_DOF_BACKBONE = "\n[analysis.backbone]\norder = 21\npoints = 4\n"


def write_two_dof_scene(folder: Path, backbone: str = TWO_DOF_BACKBONE) -> Path:
    """``two_dof.npz`` and ``scene.toml`` (:data:`TWO_DOF_SCENE`) in ``folder``; returns the scene."""
    save_system(folder / "two_dof.npz", *two_dof())
    path = folder / "scene.toml"
    path.write_text(TWO_DOF_SCENE.format(backbone=backbone))
    return path


def run_verify(capsys, *args) -> tuple[int, str, str]:
    """``stepnf verify ARGS`` in-process: exit code, stdout, stderr."""
    code = main(["verify", *map(str, args)])
    out, err = capsys.readouterr()
    return code, out, err


def polynomial_scene(d: Path, backbone: str = "order = 5\n", G_scale: float = 1.0) -> Path:
    """A 6-dof random cubic system (its G and H times ``G_scale``) and a scene with a backbone of mode 0."""
    M, K, G, H = random_system(6, seed=3)
    save_system(d / "s.npz", M, K, G_scale * G, G_scale * H)
    path = d / "s.toml"
    path.write_text('[model]\nsolver = "polynomial"\nfile = "s.npz"\n[analysis]\nmaster_modes = [0]\n'
                    f'methods = ["dnf"]\n[analysis.backbone]\n{backbone}[output]\ndir = "out"\n')
    return path

"""Plugin discovery: broken or duplicate plugins warn, unknown names list the installed ones."""
from importlib.metadata import EntryPoint

import pytest

from stepnf.errors import UnknownSolverError
from stepnf.plugin.registry import PluginWarning, build_registry, get_solver, installed_solvers


def ep(name, value):
    return EntryPoint(name=name, value=value, group="stepnf.solvers")


def test_polynomial_is_installed():
    assert "polynomial" in installed_solvers()
    assert get_solver("polynomial").__name__ == "PolynomialAdapter"


def test_unknown_name_lists_installed():
    with pytest.raises(UnknownSolverError) as e:
        get_solver("abaqus")
    assert "polynomial" in str(e.value) and "'abaqus'" in str(e.value)


def test_broken_plugin_warns_and_is_skipped():
    with pytest.warns(PluginWarning, match="failed to load"):
        reg = build_registry([ep("broken", "no_such_module_xyz:Adapter"),
                              ep("polynomial", "stepnf_polynomial:PolynomialAdapter")])
    assert list(reg) == ["polynomial"]


def test_not_an_adapter_warns():
    with pytest.warns(PluginWarning, match="not a SolverAdapter"):
        reg = build_registry([ep("bad", "json:dumps")])
    assert reg == {}


def test_duplicate_plugin_warns_and_keeps_first():
    with pytest.warns(PluginWarning, match="duplicates"):
        reg = build_registry([ep("polynomial", "stepnf_polynomial:PolynomialAdapter"),
                              ep("polynomial", "stepnf.plugin.modal_model:ModalModel")])
    assert reg["polynomial"].cls.__name__ == "PolynomialAdapter"


def test_import_stepnf_is_light():
    import subprocess
    import sys

    code = ("import sys, stepnf, stepnf.pipeline.run, stepnf.cli.main; "
            "bad = [m for m in ('dolfinx', 'ufl', 'petsc4py', 'gmsh', 'meshio', 'matplotlib') if m in sys.modules]; "
            "print(bad); sys.exit(1 if bad else 0)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr

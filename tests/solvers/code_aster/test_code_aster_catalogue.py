"""The code_aster command files against code_aster's own command catalogue, kept as facts.

``tests/data/code_aster_catalogue.json`` holds what code_aster 15's catalogue
(``code_aster/Cata/Commands/*.py`` of the ehmoussi/code_aster mirror; each fact names its file)
says about the commands and keywords stepnf's templates use: which keywords exist (and in which
BLOC), which are mandatory and when, the rules (UN_PARMI, ...) and the allowed values of the
keywords given fixed strings. The table is built, and every call checked with the
catalogue's ``SyntaxChecker.checkCommandSyntax``, by ``scripts/code_aster_catalogue.py`` from a
checkout of code_aster's sources (not in CI: the sources are not here); here every ``.comm``
variant the adapter renders (both force routes, isotropic, orthotropic with and without axes,
per-group materials, a clamped edge, the matrices job, the DKT and COQUE_3D shells) is parsed with :mod:`ast` and held to
the table, so CI guards the keywords without code_aster or its sources.
"""
from __future__ import annotations

import ast
import json
import re
from pathlib import Path
from typing import Any

import pytest

ca = pytest.importorskip("stepnf_code_aster")
pytest.importorskip("h5py")
from helpers.code_aster import ISO, cap, catalogue_adapters, from_mesh, rendered, shell_plate_med  # noqa: E402
from helpers.paths import DATA  # noqa: E402

FACTS = json.loads((DATA / "code_aster_catalogue.json").read_text())
COMMANDS = FACTS["commands"]
COMMAND_NAME = re.compile(r"^[A-Z][A-Z0-9_]*$")  # code_aster commands; CO names a result to create
NOT_COMMANDS = {"CO"}
ROUTES = ("stat_non_line", "calcul")


# --------------------------------------------------------------- the checker
def _literal(node: ast.expr) -> Any:
    try:
        return ast.literal_eval(node)
    except ValueError:
        return None  # a name, a call, an expression: not a fixed value


def _occurrences(node: ast.expr) -> list[ast.Call] | None:
    """The ``_F(...)`` occurrences of a factor keyword (one, a tuple/list, or a list comprehension)."""
    items = node.elts if isinstance(node, (ast.Tuple, ast.List)) else [node.elt] if isinstance(node, ast.ListComp) \
        else [node]
    ok = all(isinstance(c, ast.Call) and isinstance(c.func, ast.Name) and c.func.id == "_F" for c in items)
    return items if ok and items else None


def _holds(condition: str, ctx: dict[str, Any]) -> bool:
    """A catalogue BLOC condition (``equal_to``, ``is_in``, ``exists``, ``not``/``and``/``or``) on the
    keywords given plus the catalogue's defaults; one that needs a result's type (``is_type``) is taken as true."""
    env = {"equal_to": lambda k, v: ctx.get(k) == v, "is_in": lambda k, vs: ctx.get(k) in vs,
           "exists": lambda k: ctx.get(k, None) is not None}
    try:
        return bool(eval(condition, {"__builtins__": {}}, env))  # noqa: S307 - our own data file
    except NameError:
        return True


def _rule_broken(rule: dict[str, Any], present: set[str]) -> bool:
    n = sum(a in present for a in rule["args"])
    first = rule["args"][0] in present
    return {"UN_PARMI": n != 1, "AU_MOINS_UN": n < 1, "EXCLUS": n > 1, "ENSEMBLE": n not in (0, len(rule["args"])),
            "PRESENT_PRESENT": first and n != len(rule["args"]), "PRESENT_ABSENT": first and n > 1}[rule["rule"]]


def _check_level(table: dict, kws: dict[str, ast.expr], where: str, parent: dict[str, Any], errors: list[str]) -> None:
    ctx = {**table.get("defaults", {}), **parent, **{k: _literal(v) if _literal(v) is not None else v
                                                      for k, v in kws.items()}}
    for key, node in kws.items():
        if key == "reuse":
            if "reuse" not in table:
                errors.append(f"{where}: reuse= is not allowed")
            continue
        fact = table["keywords"].get(key)
        if fact is None:
            errors.append(f"{where}: keyword {key} is not one the catalogue facts list "
                          f"(known: {sorted(table['keywords'])})")
            continue
        if "in_bloc" in fact and not _holds(fact["in_bloc"], ctx):
            errors.append(f"{where}: keyword {key} exists only when {fact['in_bloc']}")
        if "factor" in fact:
            occ = _occurrences(node)
            if occ is None:
                errors.append(f"{where}: factor keyword {key} takes _F(...) occurrences")
                continue
            for o in occ:
                _check_level(fact["factor"], {k.arg: k.value for k in o.keywords}, f"{where}/{key}", ctx, errors)
            continue
        value = _literal(node)
        values = [value] if isinstance(value, str) else list(value) if isinstance(value, tuple) else []
        allowed = fact.get("into", fact.get("values_used"))
        for v in values:
            if isinstance(v, str) and allowed is not None and v not in allowed:
                errors.append(f"{where}: {key}={v!r} is not an allowed value {allowed}")
    for key, conditions in table.get("mandatory", {}).items():
        if key not in kws and any(c is None or _holds(c, ctx) for c in conditions):
            errors.append(f"{where}: mandatory keyword {key} is missing")
    for rule in table.get("rules", []):
        if rule["when"] is None or _holds(rule["when"], ctx):
            present = {a for a in rule["args"] if a in kws or table.get("defaults", {}).get(a) is not None}
            if _rule_broken(rule, present):
                errors.append(f"{where}: rule {rule['rule']}{tuple(rule['args'])} broken")


def catalogue_errors(comm: str) -> tuple[list[str], set[str]]:
    """Every disagreement of a rendered command file with the catalogue facts, and the commands it calls."""
    errors: list[str] = []
    used: set[str] = set()
    for node in ast.walk(ast.parse(comm)):
        if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and COMMAND_NAME.match(node.func.id)
                and node.func.id not in NOT_COMMANDS):
            continue
        name = node.func.id
        used.add(name)
        where = f"line {node.lineno}: {name}"
        if name not in COMMANDS:
            errors.append(f"{where}: not a command of the catalogue facts")
            continue
        kws = {k.arg: k.value for k in node.keywords}
        _check_level(COMMANDS[name], kws, where, {}, errors)
        need = FACTS["runtime"].get(name, {}).get("nonlinear_options_need", [])
        if need and _literal(kws.get("OPTION", ast.Constant(None))) is not None:
            missing = [k for k in need if k not in kws]
            if missing:
                errors.append(f"{where}: a non-linear option needs {missing} at run time (calcCalcMeca.F90)")
    nodes = list(ast.walk(ast.parse(comm)))
    results = {c.args[0].value for c in nodes if isinstance(c, ast.Call) and isinstance(c.func, ast.Name)
               and c.func.id == "CO" and c.args and isinstance(c.args[0], ast.Constant)}  # CO("name")
    results |= {t.id for a in nodes if isinstance(a, ast.Assign) and isinstance(a.value, ast.Call)
                and isinstance(a.value.func, ast.Name) and a.value.func.id in used
                for t in a.targets if isinstance(t, ast.Name)}  # name = COMMAND(...)
    for node in nodes:  # methods of code_aster results called from Python
        f = getattr(node, "func", None)
        if (isinstance(node, ast.Call) and isinstance(f, ast.Attribute) and isinstance(f.value, ast.Name)
                and f.value.id in results and f.attr not in FACTS["python_methods"]):
            errors.append(f"line {node.lineno}: method {f.attr} of a code_aster result is not in the facts")
    return errors, used


# --------------------------------------------------------------- the variants
def adapters(tmp_path: Path, route: str) -> dict[str, Any]:
    """One adapter per kind of rendered command file (:func:`helpers.code_aster.catalogue_adapters`: materials,
    groups, axes, boundary conditions, and on the STAT_NON_LINE route the DKT and COQUE_3D shells)."""
    return catalogue_adapters(tmp_path, route)


@pytest.mark.parametrize("route", ROUTES)
def test_every_rendered_command_file_agrees_with_the_catalogue(tmp_path, route):
    used: set[str] = set()
    for label, ad in adapters(tmp_path, route).items():
        for job in ("forces", "matrices"):
            errors, names = catalogue_errors(rendered(ad, tmp_path, job, label))
            assert errors == [], f"{label}, {job}.comm ({route}): {errors}"
            used |= names
    if route == "calcul":
        assert {"CALCUL", "EXTR_TABLE", "ASSE_VECTEUR", "CREA_RESU", "NUME_DDL"} <= used
    else:
        assert {"STAT_NON_LINE", "AFFE_CHAR_CINE", "CALC_CHAMP"} <= used and "CALCUL" not in used


def test_the_facts_table_has_no_command_the_templates_do_not_use(tmp_path):
    used: set[str] = set()
    for route in ROUTES:
        (tmp_path / route).mkdir()
        for label, ad in adapters(tmp_path / route, route).items():
            for job in ("forces", "matrices"):
                used |= catalogue_errors(rendered(ad, tmp_path / route, job, label))[1]
    assert used == set(COMMANDS)
    for name, fact in COMMANDS.items():  # each fact names the catalogue file it was read from
        assert re.fullmatch(r"code_aster/Cata/Commands/[a-z0-9_]+\.py", fact["file"]), name


def test_matrix_export_says_it_needs_code_aster_16():
    """getNodeAndComponentFromDOF is not in code_aster 15 (the facts say where it is): the template says >= 16."""
    text = ca.shipped_template("matrices.comm").text
    newer = [m for m, f in FACTS["python_methods"].items() if not f["in_15"] and f".{m}(" in text]
    assert newer == ["getNodeAndComponentFromDOF"] and "code_aster >= 16" in text


# -------------------------------------------------------------- must fail
MISTAKES = [
    ('DEFORMATION="GROT_GDEP"', 'DEFORMATON="GROT_GDEP"', "keyword DEFORMATON is not one"),  # misspelt keyword
    ('DEFORMATION="GROT_GDEP"', 'DEFORMATION="GROT_GDEPP"', "'GROT_GDEPP' is not an allowed value"),
    ("MODELE=model,\n    CHAM_MATER=fieldmat,", "CHAM_MATER=fieldmat,", "mandatory keyword MODELE is missing"),
    ('NOM_CHAM="FORC_NODA", NOM_CHAM_MED', 'NOM_CHAM="FORC_NODAL", NOM_CHAM_MED', "'FORC_NODAL' is not an allowed"),
    ("IMPR_RESU(", "IMPR_RESULTAT(", "IMPR_RESULTAT: not a command"),
    ('TOUT_ORDRE="OUI",\n)', ")", "rule UN_PARMI('TOUT_ORDRE',) broken"),
]
CALCUL_MISTAKES = [
    ("INCR_DEPL=u[i],", "INCR_DEPLA=u[i],", "keyword INCR_DEPLA is not one"),
    ('OPTION=("FORC_INTE_ELEM",)', 'OPTION=("FORC_INTER_ELEM",)', "'FORC_INTER_ELEM' is not an allowed value"),
    ("SIGM=zero_sigm,", "", "needs ['SIGM'] at run time"),
    ("NUME_ORDRE=1", "NUME_ORDER=1", "mandatory keyword NUME_ORDRE is missing"),
    ('VALE_K="FORC_INTE_ELEM"', 'VALE="FORC_INTE_ELEM"', "keyword VALE is not one"),
]


@pytest.mark.parametrize("route, old, new, message", [("stat_non_line", *m) for m in MISTAKES]
                         + [("calcul", *m) for m in CALCUL_MISTAKES])
def test_a_template_with_a_mistake_fails(tmp_path, route, old, new, message):
    """A user template folder (or an edited shipped template) with a misspelt keyword, a wrong value, a missing
    mandatory keyword or an unknown command is caught on the rendered file."""
    name = "forces.comm" if route == "stat_non_line" else "forces_calcul.comm"
    text = ca.shipped_template(name).text
    assert old in text
    (tmp_path / "tpl").mkdir()
    (tmp_path / "tpl" / name).write_text(text.replace(old, new, 1))
    ad = cap(tmp_path, templates="tpl", force_route=route)
    assert ad.templates[name].source == str(tmp_path / "tpl" / name)
    errors, _ = catalogue_errors(rendered(ad, tmp_path, "forces", "mistake"))
    assert any(message in e for e in errors), errors


@pytest.mark.parametrize("old, new, message", [
    ("stiffness.EXTR_MATR(", "stiffness.EXTR_MATRIX(", "method EXTR_MATRIX of a code_aster result"),
    ('OPTION="RIGI_MECA"', 'OPTION="RIGI_MECAS"', "'RIGI_MECAS' is not an allowed value"),
    ('NUME_DDL=CO("numbering"),', "", "mandatory keyword NUME_DDL is missing"),
])
def test_a_matrices_template_with_a_mistake_fails(tmp_path, old, new, message):
    text = ca.shipped_template("matrices.comm").text
    assert old in text
    (tmp_path / "tpl").mkdir()
    (tmp_path / "tpl" / "matrices.comm").write_text(text.replace(old, new, 1))
    errors, _ = catalogue_errors(rendered(cap(tmp_path, templates="tpl"), tmp_path, "matrices", "mistake"))
    assert any(message in e for e in errors), errors


# ------------------------------------------------------------------ shells
def _shell(tmp_path: Path, element: str, **kw):
    kind = "quad9" if element == "coque_3d" else "quad"
    return from_mesh(tmp_path, shell_plate_med(tmp_path, kind), material=ISO, element=element, thickness=0.003, **kw)


@pytest.mark.parametrize("element, modelisation", [("dkt", "DKT"), ("coque_3d", "COQUE_3D")])
def test_shell_command_files_agree_with_the_catalogue(tmp_path, element, modelisation):
    """DKT and COQUE_3D: the modelisation, AFFE_CARA_ELEM COQUE EPAIS, the six imposed dofs, GROT_GDEP, one
    STAT_NON_LINE per field from the reference state, and the rotational dofs' matrices, all in the catalogue."""
    ad = _shell(tmp_path, element)
    forces, matrices = (rendered(ad, tmp_path, job, element) for job in ("forces", "matrices"))
    for text in (forces, matrices):
        errors, used = catalogue_errors(text)
        assert errors == [] and "AFFE_CARA_ELEM" in used, errors
        assert f'MODELISATION="{modelisation}"' in text and "COQUE=_F(GROUP_MA=\"STEPNF_SHELL\", EPAIS=0.003" in text
        assert "CARA_ELEM=cara," in text
    assert 'NOM_CMP=("DX", "DY", "DZ", "DRX", "DRY", "DRZ")' in forces and 'DEFORMATION="GROT_GDEP"' in forces
    assert "INST_INIT=float(i - 1), INST_FIN=float(i)" in forces and "ETAT_INIT=" not in forces


def test_every_modelisation_run_with_grot_gdep_has_a_runtime_fact(tmp_path):
    """The command catalogue does not say which modelisation takes DEFORMATION="GROT_GDEP": the facts name the
    element routine that does, for every modelisation a rendered force job runs with it."""
    used = set()
    for label, ad in adapters(tmp_path, "stat_non_line").items():
        text = rendered(ad, tmp_path, "forces", label)
        if 'DEFORMATION="GROT_GDEP"' in text:
            used |= set(re.findall(r'MODELISATION="([A-Z_0-9]+)"', text))
    facts = FACTS["runtime"]["GROT_GDEP"]["modelisations"]
    assert used == {"3D", "DKT", "COQUE_3D"} and used <= set(facts)
    assert "dktnli.F90" in facts["DKT"] and "te0414.F90" in facts["COQUE_3D"]


@pytest.mark.parametrize("old, new, message", [
    ("EPAIS=${thickness}", "EPAISSEUR=${thickness}", "keyword EPAISSEUR is not one"),
    ("COQUE=_F(GROUP_MA=${shell_group_py}, ", "COQUE=_F(TOUT=\"OUI\", ", "keyword TOUT is not one"),
    ('MODELISATION=${modelisation_py}', 'MODELISATION="DKTT"', "'DKTT' is not an allowed value"),
    ("INST_INIT=float(i - 1)", "INST_INITIAL=float(i - 1)", "keyword INST_INITIAL is not one"),
    ('"DRX", "DRY", "DRZ"))', '"DRX", "DRY", "DRZ"), TOUT="OUI")', "keyword TOUT is not one"),
])
def test_a_shell_template_with_a_mistake_fails(tmp_path, old, new, message):
    text = ca.shipped_template("forces_shell.comm").text
    assert old in text
    (tmp_path / "tpl").mkdir()
    (tmp_path / "tpl" / "forces_shell.comm").write_text(text.replace(old, new, 1))
    ad = _shell(tmp_path, "dkt", templates="tpl")
    errors, _ = catalogue_errors(rendered(ad, tmp_path, "forces", "mistake"))
    assert any(message in e for e in errors), errors

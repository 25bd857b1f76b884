"""Build ``tests/data/code_aster_catalogue.json`` from code_aster's own command catalogue (run by hand, not by CI).

Usage (from the repository root, with the project's Python)::

    git clone https://github.com/ehmoussi/code_aster /tmp/code_aster   # the public mirror; commit 34161d79 (15.2)
    .venv/bin/python scripts/code_aster_catalogue.py /tmp/code_aster [--out tests/data/code_aster_catalogue.json]

Every command file the adapter renders (the variants of :func:`helpers.code_aster.catalogue_variants`: both
solid force routes, isotropic, orthotropic, per-group materials, a clamped edge, the matrices job, and the
DKT and COQUE_3D shells) is run as Python with each code_aster command replaced by a recorder: each call
is checked by the catalogue's own ``SyntaxChecker.checkCommandSyntax`` (a failure stops the build), and the
facts the CI test needs are read from the catalogue objects (``code_aster/Cata/Commands/<file>.py``) for
the keywords the calls use: ``keywords`` (``in_bloc``: the conditions of the BLOCs holding it, joined by
``and``; ``into`` up to 20 values, else ``into_size``, with ``values_used``; ``factor``: the same one level
down; ``defined_in``: the Commons function that builds it), ``mandatory`` (statut ``'o'`` without default,
in the BLOCs some call enables), ``rules`` (cut down to the keywords used; ``of``: the catalogue rule's
length when cut), ``defaults`` (of the keywords the kept conditions and rules name) and ``reuse``. The
``python_methods`` and ``runtime`` sections (read from the sources by hand, see their ``source``) are kept.
"""
from __future__ import annotations

import argparse
import copy
import json
import re
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
RULES = {"ExactlyOne": "UN_PARMI", "AtLeastOne": "AU_MOINS_UN", "AtMostOne": "EXCLUS", "AllTogether": "ENSEMBLE",
         "IfFirstAllPresent": "PRESENT_PRESENT", "OnlyFirstPresent": "PRESENT_ABSENT"}
NOT_COMMANDS = {"CO", "_F"}


def load_catalogue(source: Path):
    import numpy as np

    for alias, builtin in (("int", int), ("float", float), ("complex", complex), ("bool", bool)):
        if alias not in vars(np):  # the 2020 checker uses numpy's aliases that numpy 1.24 removed
            setattr(np, alias, builtin)
    sys.path.insert(0, str(source))
    from code_aster.Cata import Commands  # noqa: E402
    from code_aster.Cata.Language import DataStructure as DS  # noqa: E402
    from code_aster.Cata.Language.SyntaxChecker import checkCommandSyntax  # noqa: E402
    from code_aster.Cata.Language.SyntaxObjects import Bloc, FactorKeyword, SimpleKeyword, _F  # noqa: E402

    return Commands, DS, checkCommandSyntax, (Bloc, FactorKeyword, SimpleKeyword, _F)


def record_calls(text: str, Commands, DS, F) -> list[tuple[str, dict]]:
    """Run a rendered command file with every code_aster command recording its keywords."""
    calls: list[tuple[str, dict]] = []

    class Result(DS.CO):
        """``CO("name")``: a result a macro command creates and types (code_aster's own CO has it at run time)."""

        def settype(self, typ):
            return None

    def command(name):
        cmd = getattr(Commands, name)

        def call(**kw):
            calls.append((name, copy.deepcopy({k: v for k, v in kw.items()})))
            try:
                typ = cmd.get_type_sd_prod(**kw)
            except Exception:  # noqa: BLE001 - a sd_prod function that needs what a recorder lacks
                typ = None
            return typ() if isinstance(typ, type) and issubclass(typ, DS.DataStructure) else DS.PythonVariable()
        return call

    names = {n for n in re.findall(r"\b([A-Z][A-Z0-9_]*)\(", text) if n not in NOT_COMMANDS and hasattr(Commands, n)}
    glob = {"__builtins__": __builtins__, "_F": F, "CO": lambda name: Result(), **{n: command(n) for n in names}}
    try:
        exec(compile(text, "<comm>", "exec"), glob)  # noqa: S102 - our own rendered templates
    except (NameError, AttributeError):
        pass  # past the last command: methods of results (EXTR_MATR, ...) are not the catalogue's
    return calls


def _condition(bloc) -> str:
    return " ".join(bloc.getCondition().split())


def _levels(entity, Bloc, cond=None, out=None, rules=None):
    """``(name -> [(keyword object, condition)], [(rule, condition)])`` of a command or factor keyword."""
    out = {} if out is None else out
    rules = [] if rules is None else rules
    for r in getattr(entity, "rules", None) or []:
        rules.append((r, cond))
    for name, obj in entity.definition.items():
        if isinstance(obj, Bloc):
            c = _condition(obj)
            _levels(obj, Bloc, c if cond is None else f"{cond} and {c}", out, rules)
        elif hasattr(obj, "definition") and not isinstance(obj, str):
            out.setdefault(name, []).append((obj, cond))
    return out, rules


def _enabled(entity, occurrences: list[dict], Bloc, defaults: dict) -> set[str | None]:
    """The conditions (joined as :func:`_levels` joins them) that some occurrence enables."""
    found: set[str | None] = {None}

    def walk(ent, cond, ctx):
        for obj in ent.definition.values():
            if isinstance(obj, Bloc) and obj.isEnabled(ctx):
                c = _condition(obj)
                joined = c if cond is None else f"{cond} and {c}"
                found.add(joined)
                walk(obj, joined, ctx)

    for occ in occurrences:
        walk(entity, None, {**defaults, **occ})
    return found


def facts(entity, occurrences: list[dict], objs) -> dict[str, Any]:
    Bloc, FactorKeyword, SimpleKeyword, _ = objs
    by_name, rules = _levels(entity, Bloc)
    all_defaults = {n: o.definition.get("defaut") for n, lst in by_name.items() for o, _ in lst
                    if o.definition.get("defaut") is not None}
    enabled = _enabled(entity, occurrences, Bloc, all_defaults)
    used = [k for occ in occurrences for k in occ if k != "reuse"]
    used = list(dict.fromkeys(used))
    table: dict[str, Any] = {"keywords": {}}
    named: set[str] = set()
    for key in sorted(used):
        choices = [(o, c) for o, c in by_name.get(key, []) if c in enabled] or by_name.get(key, [])
        if not choices:
            table["keywords"][key] = {"unknown": True}
            continue
        obj, cond = choices[0]
        fact: dict[str, Any] = {}
        if cond is not None:
            fact["in_bloc"] = cond
            named |= set(re.findall(r"[\"']([A-Z][A-Z0-9_]*)[\"']", cond))
        if isinstance(obj, FactorKeyword):
            occ = [dict(o) for v in (occ.get(key) for occ in occurrences) if v is not None
                   for o in (v if isinstance(v, (list, tuple)) else [v])]
            fact["factor"] = facts(obj, occ, objs)
        else:
            into = obj.definition.get("into")
            if into is not None:
                values = []
                for occ in occurrences:
                    v = occ.get(key)
                    for x in (v if isinstance(v, (list, tuple)) else [v]):
                        if isinstance(x, str) and x not in values:
                            values.append(x)
                fact.update({"into": list(into)} if len(into) <= 20 else {"into_size": len(into)})
                fact["values_used"] = values
        table["keywords"][key] = fact
    mandatory: dict[str, list] = {}
    for name, lst in by_name.items():
        for obj, cond in lst:
            if cond in enabled and obj.definition.get("statut") == "o" and obj.definition.get("defaut") is None:
                mandatory.setdefault(name, []).append(cond)
                if cond:
                    named |= set(re.findall(r"[\"']([A-Z][A-Z0-9_]*)[\"']", cond))
    if mandatory:
        table["mandatory"] = {k: mandatory[k] for k in sorted(mandatory)}
    kept = []
    for rule, cond in rules:
        kind = RULES.get(type(rule).__name__)
        args = [a for a in rule.ruleArgs if a in used]
        if kind is None or not args or cond not in enabled:
            continue
        cut = len(args) != len(rule.ruleArgs)
        if ((kind in ("PRESENT_PRESENT", "PRESENT_ABSENT") and args[0] != rule.ruleArgs[0])
                or (kind == "EXCLUS" and len(args) < 2) or (kind == "ENSEMBLE" and cut)):
            continue  # cut down, the rule cannot fire on the keywords used (or cannot be said of them)
        r = {"args": args, "rule": kind, "when": cond}
        if len(args) != len(rule.ruleArgs):
            r["of"] = len(rule.ruleArgs)
        kept.append(dict(sorted(r.items())))
        named |= set(args) | (set(re.findall(r"[\"']([A-Z][A-Z0-9_]*)[\"']", cond)) if cond else set())
    if kept:
        table["rules"] = kept
    defaults = {k: all_defaults[k] for k in sorted(named) if k in all_defaults}
    if defaults:
        table["defaults"] = defaults
    return table


def defined_in(source: Path, file: str, key: str) -> str | None:
    text = (source / file).read_text(encoding="utf-8", errors="replace")
    m = re.search(rf"\b{key}\s*=\s*(C_[A-Z_0-9]+)\(([^)]*)\)", text)
    if not m:
        return None
    return f"code_aster/Cata/Commons/{m.group(1).lower()}.py ({m.group(1)}({m.group(2).strip()}))"


def build(source: Path, texts: dict[str, str]) -> tuple[dict[str, Any], list[str]]:
    Commands, DS, check, objs = load_catalogue(source)
    calls: dict[str, list[dict]] = {}
    errors = []
    for label, text in texts.items():
        for name, kw in record_calls(text, Commands, DS, objs[3]):
            calls.setdefault(name, []).append(kw)
            try:
                check(getattr(Commands, name), copy.deepcopy(kw))
            except Exception as exc:  # noqa: BLE001 - the checker raises several kinds
                errors.append(f"{label}: {name}: {type(exc).__name__}: {exc}")
    out = {}
    for name in sorted(calls):
        cmd = getattr(Commands, name)
        file = _file_of(source, name)
        t = facts(cmd, calls[name], objs)
        for key, fact in t["keywords"].items():
            where = defined_in(source, file, key) if "factor" in fact else None
            if where:
                fact["defined_in"] = where
        reentrant = cmd.definition.get("reentrant", "n")
        table = {"file": file, **t}
        if reentrant and reentrant[0] in "of" and any("reuse" in kw for kw in calls[name]):
            table["reuse"] = reentrant
        out[name] = dict(sorted(table.items()))
    return out, errors


def _file_of(source: Path, name: str) -> str:
    path = source / "code_aster/Cata/Commands" / f"{name.lower()}.py"
    if path.is_file():
        return str(path.relative_to(source))
    for p in sorted((source / "code_aster/Cata/Commands").glob("*.py")):
        if re.search(rf"^{name}\s*=", p.read_text(encoding="utf-8", errors="replace"), re.M):
            return str(p.relative_to(source))
    raise SystemExit(f"no catalogue file defines {name}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("source", type=Path, help="a checkout of code_aster's sources (holding code_aster/Cata)")
    ap.add_argument("--out", type=Path, default=ROOT / "tests/data/code_aster_catalogue.json")
    args = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT / "tests"))
    from helpers.code_aster import catalogue_variants  # noqa: E402

    with tempfile.TemporaryDirectory() as tmp:
        texts = catalogue_variants(Path(tmp))
    commands, errors = build(args.source.resolve(), texts)
    if errors:
        print("\n".join(errors), file=sys.stderr)
        return 1
    old = json.loads(args.out.read_text()) if args.out.is_file() else {}
    data = {k: old[k] for k in ("_about", "source") if k in old}
    data["commands"] = commands
    data.update({k: old[k] for k in ("python_methods", "runtime") if k in old})
    args.out.write_text(json.dumps(data, indent=1, sort_keys=False) + "\n")
    print(f"{len(texts)} command files, {sum(1 for _ in commands)} commands, every call passed checkCommandSyntax: "
          f"{args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""The project's import graph read from the source (no module is imported): every ``import``,
``from ... import`` (relative ones resolved against the module's package) and
``importlib.import_module("...")`` / ``__import__("...")`` with a constant name, lazy in-function
and ``TYPE_CHECKING`` ones included -- an edge a path may take is an edge. Used by the layer test
(order of packages and of identify's wings, no cycles) and by ``docs/architecture.py`` (the picture).
"""
from __future__ import annotations

import ast
from pathlib import Path

PACKAGES = ("identify", "signaldesign", "cueing", "campaign")  # bottom to top: imports point down
# identify's rooms, bottom to top: a module may import its own wing and those below it. The hall's
# errors and command-line plumbing sit under everything; the pipeline of one identification (read, fit,
# check, write) above the rooms it runs; the command line and the lazy facade on top.
WINGS = {"errors": 0, "_version": 0, "cliutil": 0, "data": 1, "model": 2, "estimators": 3, "refine": 4, "compat": 5,
         "structure": 5, "pipeline": 6, "commands": 7, "cli": 7, "__main__": 7}
FACADE = 7  # identify/__init__.py: names imported on first use from every wing


def modules(root: Path, packages=PACKAGES) -> dict[str, Path]:
    """``{dotted module name: file}`` of every module of the packages present under ``root``."""
    out = {}
    for pkg in packages:
        for f in sorted((root / pkg).rglob("*.py")) if (root / pkg).is_dir() else []:
            parts = list(f.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            out[".".join(parts)] = f
    return out


def _resolve(module: str | None, level: int, package: str) -> str:
    if not level:
        return module or ""
    base = package.split(".")
    base = base[:len(base) - (level - 1)] if level > 1 else base
    return ".".join(base + ([module] if module else []))


def imports(name: str, source: str, known: set[str], filename: str = "<source>") -> list[tuple[int, str]]:
    """``(line, module)`` of every project module (one of ``known``, or of :data:`PACKAGES`) that
    module ``name`` imports; ``name`` ending in ``.__init__`` or being a package uses itself as the
    package for relative imports."""
    package = name if name in _packages(known) else name.rpartition(".")[0]
    found = []
    for node in ast.walk(ast.parse(source, filename)):
        targets = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = _resolve(node.module, node.level, package)
            # ``from pkg import sub`` imports the submodule; ``from mod import name`` the module
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in known else base for a in node.names]
        elif (isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", None))
              in ("import_module", "__import__") and node.args and isinstance(node.args[0], ast.Constant)
              and isinstance(node.args[0].value, str)):
            target = node.args[0].value
            if target.startswith("."):  # import_module(".x", __package__ / __name__)
                level = len(target) - len(target.lstrip("."))
                target = _resolve(target.lstrip(".") or None, level, package)
            targets = [target]
        for t in targets:
            t = _nearest(t, known)
            if t and t.split(".")[0] in PACKAGES:
                found.append((node.lineno, t))
    return found


def _packages(known: set[str]) -> set[str]:
    return {m.rpartition(".")[0] for m in known if "." in m}


def _nearest(target: str, known: set[str]) -> str | None:
    """The module a dotted name lands in (``identify.estimators.ml.ML`` -> ``identify.estimators.ml``)."""
    parts = target.split(".")
    while parts:
        if ".".join(parts) in known:
            return ".".join(parts)
        parts.pop()
    return target if target.split(".")[0] in PACKAGES else None


def graph(root: Path, packages=PACKAGES) -> dict[str, set[str]]:
    """``{module: modules it imports}`` over the packages (self-imports and a module's own
    parent packages left out: Python runs those first anyway, they are no dependency)."""
    mods = modules(root, packages)
    known = set(mods)
    out = {}
    for name, path in mods.items():
        edges = {t for _, t in imports(name, path.read_text(), known, str(path))}
        out[name] = {t for t in edges if t != name and not name.startswith(t + ".")}
    return out


def cycles(g: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan), each sorted."""
    index, low, stack, on, out = {}, {}, [], set(), []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in g.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(g):
        if v not in index:
            visit(v)
    return out


def wing_rank(module: str) -> int | None:
    """Rank of an identify module in :data:`WINGS` (None: not in identify; KeyError: a room the
    order does not know yet -- place it in WINGS)."""
    parts = module.split(".")
    if parts[0] != "identify":
        return None
    return FACADE if len(parts) == 1 else WINGS[parts[1]]


def wing_violations(g: dict[str, set[str]]) -> list[str]:
    """``module -> imported`` for every import inside identify that points to a higher wing."""
    return [f"{m} -> {t}" for m in sorted(g) for t in sorted(g[m])
            if wing_rank(m) is not None and wing_rank(t) is not None and wing_rank(t) > wing_rank(m)]


def private_reads(source: str, filename: str = "<source>") -> list[str]:
    """``file:line name`` of every read of another module's ``_private`` attribute: ``x._name``
    with x not ``self``/``cls``/``super()`` and ``_name`` not defined in this module (a copy of
    one's own object may be read), and every ``from m import _name``."""
    tree = ast.parse(source, filename)
    own = {n.name for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.ClassDef))} | {
        n.attr for n in ast.walk(tree) if isinstance(n, ast.Attribute) and isinstance(n.ctx, ast.Store)}
    hits = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and _private(node.attr):
            owner = node.value
            if isinstance(owner, ast.Name) and owner.id in ("self", "cls") or node.attr in own:
                continue
            if isinstance(owner, ast.Call) and getattr(owner.func, "id", None) == "super":
                continue
            hits.append(f"{filename}:{node.lineno} .{node.attr}")
        elif isinstance(node, ast.ImportFrom):
            hits += [f"{filename}:{node.lineno} import {a.name}" for a in node.names if _private(a.name)]
    return hits


def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))

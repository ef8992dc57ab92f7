"""The layer rule: imports point down only (identify <- signaldesign <- cueing <- campaign), inside
identify too (data < model < estimators < refine < compat), and no import cycle anywhere.

Every module of a layer is imported in a fresh interpreter with the layers above it blocked (an
import of them raises); the source's import graph (:mod:`tests.importgraph`: relative imports
resolved, lazy in-function ones and ``importlib.import_module("...")`` included, since they run
only on some paths) is checked for upward edges between packages and wings and for cycles. The
seams between rooms: no module reads another's ``_private`` attribute, refine and the command line
never branch on an estimator's name, and ``identify estimate`` loads nothing of the refine wing.
"""
import ast
import os
import re
import subprocess
import sys
import textwrap

import pytest

from tests import importgraph as ig
from tests.helpers import ROOT

ABOVE = {"identify": ("signaldesign", "cueing", "campaign"), "signaldesign": ("cueing", "campaign"),
         "cueing": ("campaign",)}

_BLOCKED_IMPORT = textwrap.dedent("""
    import importlib, pkgutil, sys

    class Blocker:
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in BLOCKED:
                raise ImportError(f"layer rule: {name} imported from below")
            return None

    sys.meta_path.insert(0, Blocker())
    package = importlib.import_module(PACKAGE)
    names = [PACKAGE] + [m.name for m in pkgutil.walk_packages(package.__path__, PACKAGE + ".")
                         if not m.name.endswith(".__main__")]  # __main__ runs the command line
    for name in names:
        importlib.import_module(name)
    print(len(names))
""")


@pytest.mark.parametrize("package", sorted(ABOVE))
def test_every_module_imports_with_the_layers_above_blocked(package):
    code = f"PACKAGE = {package!r}\nBLOCKED = {ABOVE[package]!r}\n" + _BLOCKED_IMPORT
    env = dict(os.environ, PYTHONPATH=str(ROOT), MPLBACKEND="Agg")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, env=env,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert int(proc.stdout.split()[-1]) > 5  # the package and its submodules, not just __init__


def _package_violations(g: dict[str, set[str]]) -> list[str]:
    rank = {p: i for i, p in enumerate(ig.PACKAGES)}
    return [f"{m} -> {t}" for m in sorted(g) for t in sorted(g[m])
            if rank[t.split(".")[0]] > rank[m.split(".")[0]]]


def _graph_of(sources: dict[str, str]) -> dict[str, set[str]]:
    """The import graph of made-up modules ``{name: source}`` (plus the real ones they name)."""
    known = set(ig.modules(ROOT)) | set(sources)
    return {name: {t for _, t in ig.imports(name, textwrap.dedent(src), known)} - {name}
            for name, src in sources.items()}


@pytest.fixture(scope="module")
def graph():
    return ig.graph(ROOT)


def test_no_upward_import_between_packages(graph):
    assert len(graph) > 60  # every module of every package read
    assert not _package_violations(graph), "upward imports:\n" + "\n".join(_package_violations(graph))


def test_wings_inside_identify_in_order(graph):
    assert not ig.wing_violations(graph), "upward imports between identify's wings:\n" + \
        "\n".join(ig.wing_violations(graph))


def test_no_import_cycle_anywhere(graph):
    found = ig.cycles(graph)
    assert found == [], "import cycles:\n" + "\n".join(" <-> ".join(c) for c in found)


def test_the_checks_see_lazy_relative_dynamic_and_cyclic_imports():
    """The scan fails where it must: an upward package import (lazy, dynamic), a ``data`` module
    importing ``refine`` (relative or by importlib name), and a cycle."""
    g = _graph_of({
        "identify.data.bad": """
            from ..refine.loop import Refine
            def later():
                from cueing.session import fly
                import signaldesign.design
                return importlib.import_module("identify.refine.report")
            """,
        "identify.data.dyn": "importlib.import_module('..refine', __package__)",
        "identify.model.a": "from . import b",
        "identify.model.b": "from .a import x",
    })
    assert g["identify.data.bad"] == {"identify.refine.loop", "identify.refine.report", "cueing.session",
                                      "signaldesign.design"}
    assert g["identify.data.dyn"] == {"identify.refine"}
    assert set(ig.wing_violations(g)) == {"identify.data.bad -> identify.refine.loop",
                                          "identify.data.bad -> identify.refine.report",
                                          "identify.data.dyn -> identify.refine"}
    assert _package_violations(g) == ["identify.data.bad -> cueing.session",
                                      "identify.data.bad -> signaldesign.design"]
    assert ig.cycles(g) == [["identify.model.a", "identify.model.b"]]


def test_no_module_reads_another_modules_private_attributes():
    hits = [h for f in ig.modules(ROOT).values() for h in ig.private_reads(f.read_text(), str(f.relative_to(ROOT)))]
    assert not hits, "private attributes read across modules:\n" + "\n".join(hits)
    made_up = textwrap.dedent("""
        from .result import _jsonable
        class A:
            def __init__(self):
                self._mine = 1
            def copy(self, other):
                return other._mine + self._mine + super()._x
        def report(r):
            return r._raw
        """)
    assert [h.split()[-1] for h in ig.private_reads(made_up)] == ["_jsonable", "._raw"]


def test_no_pyplot_state_in_library_code():
    """Figures on an Agg canvas (``matplotlib.figure.Figure``), never pyplot's global state or a
    ``matplotlib.use()`` that switches a caller's backend."""
    pattern = re.compile(r"matplotlib\.pyplot|from matplotlib import .*pyplot|matplotlib\.use\(")
    hits = [f"{f.relative_to(ROOT)}:{i}" for f in ig.modules(ROOT).values()
            for i, line in enumerate(f.read_text().splitlines(), 1) if pattern.search(line)]
    assert not hits, hits


def _estimator_name_branches(source: str, filename: str) -> list[str]:
    """Comparisons with, and dict keys of, an estimator's method name (``method == "ml"``,
    ``{"ml": ...}[args.method]``)."""
    from identify.estimators.registry import METHOD_NAMES

    hits = []
    for node in ast.walk(ast.parse(source, filename)):
        consts = []
        if isinstance(node, ast.Compare):
            consts = [c for c in ast.walk(node) if isinstance(c, ast.Constant)]
        elif isinstance(node, ast.Dict):
            consts = [k for k in node.keys if isinstance(k, ast.Constant)]
        hits += [f"{filename}:{c.lineno} {c.value!r}" for c in consts if c.value in METHOD_NAMES]
    return hits


def test_refine_the_pipeline_and_the_command_line_never_branch_on_an_estimator_name():
    files = [f for room in ("refine", "pipeline", "commands") for f in sorted((ROOT / "identify" / room).glob("*.py"))]
    files.append(ROOT / "identify" / "cli.py")
    hits = [h for f in files for h in _estimator_name_branches(f.read_text(), str(f.relative_to(ROOT)))]
    assert not hits, hits
    made_up = 'x = {"ls": 1}[m] if method == "ml" else 0'
    assert sorted(_estimator_name_branches(made_up, "<s>")) == ["<s>:1 'ls'", "<s>:1 'ml'"]


def test_identify_estimate_loads_nothing_of_the_refine_wing(tmp_path):
    """``identify estimate`` runs without importing any module of identify/refine/ (LS, the cheap
    path: every method passes through the check for state-built terms that fits them as refine does)."""
    code = textwrap.dedent(f"""
        import sys
        import numpy as np
        from identify import LinearModel, load_profile, simulate_run
        from identify.cli import main
        p = load_profile("s61_hover_4dof")
        t = np.arange(0, 8, 0.02)
        u = np.zeros((t.size, 2)); u[50:100, 0] = 0.01; u[150:200, 1] = 0.01
        run = simulate_run(LinearModel(p), t, u, noise_fraction=0.02, seed=1)
        run.to_csv({str(tmp_path / "run.csv")!r})
        status = main(["estimate", {str(tmp_path / "run.csv")!r}, "--profile", "s61_hover_4dof",
                       "--method", "ls", "--out", {str(tmp_path / "out")!r}])
        print(status, sorted(m for m in sys.modules if m.startswith("identify.refine")))
    """)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT,
                          env=dict(os.environ, PYTHONPATH=str(ROOT), MPLBACKEND="Agg"), timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split("\n")[-2] == "0 []", proc.stdout[-500:]


def test_import_identify_leaves_out_the_slow_optional_libraries():
    """python-control (only LinearModel.to_ss) and matplotlib (only plots) load when used."""
    code = "import sys, identify; print(sorted(m for m in ('control', 'matplotlib') if m in sys.modules))"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT,
                          env=dict(os.environ, PYTHONPATH=str(ROOT)), timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "[]"


@pytest.mark.parametrize("package, heavy", [
    ("identify", ("control", "matplotlib", "scipy.signal", "scipy.stats")),
    ("signaldesign", ("control", "matplotlib", "scipy.signal")),
    ("identify.cli", ("control", "matplotlib", "scipy", "identify.estimators.ml")),
    ("signaldesign.cli", ("control", "matplotlib", "scipy.signal")),
])
def test_imports_and_help_load_no_heavy_library(package, heavy):
    """``import identify`` and the command lines' parsers (``--help``) load none of the slow
    libraries (python-control 0.65 s, scipy.signal 0.4 s, matplotlib): names are imported on
    first use. Their timings are printed by benchmarks/ml_speed.py, not asserted here."""
    code = (f"import sys, importlib; m = importlib.import_module({package!r}); "
            f"getattr(m, 'build_parser', lambda: None)(); "
            f"print(','.join(h for h in {heavy!r} if h in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT,
                         env=dict(os.environ, PYTHONPATH=str(ROOT)), timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "", f"{package} loads {out.stdout.strip()}"


def test_lazy_names_resolve():
    import identify
    import signaldesign
    for name in identify.__all__:
        assert getattr(identify, name) is not None, name
    for name in signaldesign.__all__:
        assert getattr(signaldesign, name) is not None, name


def test_the_architecture_page_is_the_import_graph():
    """docs/architecture.md holds the picture docs/architecture.py draws from the source: a new
    import that changes the picture must regenerate the page (``python docs/architecture.py --write``)."""
    import importlib.util
    spec = importlib.util.spec_from_file_location("architecture", ROOT / "docs" / "architecture.py")
    arch = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(arch)
    page = (ROOT / "docs" / "architecture.md").read_text()
    held = page.partition(arch.BEGIN)[2].partition(arch.END)[0].strip()
    assert held == arch.picture(ig.graph(ROOT)).strip(), "regenerate: python docs/architecture.py --write"

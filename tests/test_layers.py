"""The layer rule: imports point down only (identify <- signaldesign <- cueing <- campaign).

Two checks: every module of a layer is imported in a fresh interpreter with the layers above it
blocked (an import of them raises), and the source is scanned for upward imports anywhere, lazy
in-function ones and ``importlib.import_module("...")`` included (they run only on some paths).
"""
import ast
import os
import subprocess
import sys
import textwrap

import pytest

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


def upward_imports(source: str, package: str, filename: str = "<source>") -> list[str]:
    """``file:line module`` of every import in ``source`` of a layer above ``package``."""
    hits = []
    for node in ast.walk(ast.parse(source, filename)):
        if isinstance(node, ast.Import):
            modules = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            modules = [node.module]
        elif (isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", None))
              in ("import_module", "__import__") and node.args and isinstance(node.args[0], ast.Constant)
              and isinstance(node.args[0].value, str)):
            modules = [node.args[0].value]
        else:
            continue
        hits += [f"{filename}:{node.lineno} {m}" for m in modules if m.split(".")[0] in ABOVE[package]]
    return hits


@pytest.mark.parametrize("package", sorted(ABOVE))
def test_every_module_imports_with_the_layers_above_blocked(package):
    code = f"PACKAGE = {package!r}\nBLOCKED = {ABOVE[package]!r}\n" + _BLOCKED_IMPORT
    env = dict(os.environ, PYTHONPATH=str(ROOT), MPLBACKEND="Agg")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, env=env,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert int(proc.stdout.split()[-1]) > 5  # the package and its submodules, not just __init__


@pytest.mark.parametrize("package", sorted(ABOVE))
def test_no_upward_import_anywhere_in_the_source(package):
    files = sorted((ROOT / package).rglob("*.py"))
    assert files
    hits = [h for f in files for h in upward_imports(f.read_text(), package, str(f.relative_to(ROOT)))]
    assert not hits, "upward imports:\n" + "\n".join(hits)


def test_the_scan_sees_lazy_and_dynamic_upward_imports():
    source = textwrap.dedent("""
        import numpy
        from .model import LinearModel
        def later():
            from cueing.session import fly
            import signaldesign.design
            return importlib.import_module("signaldesign.band")
    """)
    hits = upward_imports(source, "identify")
    assert [h.split()[-1] for h in hits] == ["cueing.session", "signaldesign.design", "signaldesign.band"]
    assert upward_imports(source, "signaldesign") == ["<source>:5 cueing.session"]


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

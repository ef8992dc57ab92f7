"""Install as users install: the wheel and the sdist built from this tree, every module of the tree in
the wheel, and the tool run from the wheel in a fresh virtual environment (not editable, not the
source tree) on `examples/`: every registered method, refine, compat, freq, hq, signaldesign design,
cueing fly --headless and the campaign.

The fresh environment takes its dependencies (numpy, scipy, Dask, ...) from the test's own
environment through a path file, so the test needs no download; the packages under test come from
the wheel alone: the editable install's finder is not loaded there, and every command runs outside
the source tree.
"""
import os
import shutil
import subprocess
import sys
import sysconfig
import tarfile
import venv
import zipfile
from pathlib import Path

import pytest

from identify.estimators.registry import METHOD_NAMES

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("identify", "signaldesign", "cueing", "campaign")
EX = ROOT / "examples"


def _tree_modules() -> set[str]:
    """Every importable module of the tree, as a wheel path (``identify/estimators/ml.py``)."""
    return {p.relative_to(ROOT).as_posix() for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")
            if "__pycache__" not in p.parts}


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """(wheel, sdist) built by setuptools' own backend (no network) from a copy of the tree, so that
    the build's folders never land in the tree or race another test worker."""
    src = tmp_path_factory.mktemp("src") / "pseudostep"
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns(".venv", ".git", "build", "*.egg-info", "__pycache__",
                                                             "output", "demo-output", ".pytest_cache"))
    out = tmp_path_factory.mktemp("dist")
    code = f"from setuptools import build_meta as b; b.build_wheel({str(out)!r}); b.build_sdist({str(out)!r})"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=src)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return next(out.glob("pseudostep-*.whl")), next(out.glob("pseudostep-*.tar.gz"))


@pytest.fixture(scope="module")
def user_venv(built, tmp_path_factory):
    """A fresh venv holding the wheel (not editable); dependencies reached through a .pth file."""
    where = tmp_path_factory.mktemp("venv")
    venv.create(where, with_pip=False)
    py = where / "bin" / "python"
    site = Path(subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               capture_output=True, text=True, check=True).stdout.strip())
    # the test's environment for numpy & co.; a path in a .pth is added as it is, its own .pth files
    # (the editable install's finder among them) are not read
    (site / "_deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    proc = subprocess.run([sys.executable, "-m", "pip", "--python", str(py), "install", "--no-deps",
                           "--no-index", "-q", str(built[0])], capture_output=True, text=True)
    if proc.returncode != 0 and "no such option: --python" in proc.stderr:  # pip < 22.3
        proc = subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "--no-index", "-q",
                               "--target", str(site), str(built[0])], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    return where


def test_wheel_holds_every_module_and_profile(built):
    wheel, sdist = built
    names = set(zipfile.ZipFile(wheel).namelist())
    missing = sorted(_tree_modules() - names)
    assert not missing, f"not in the wheel: {missing}"
    assert {f"profiles/{p.name}" for p in (ROOT / "profiles").glob("*.toml")} <= names
    with tarfile.open(sdist) as tar:
        in_sdist = {n.split("/", 1)[1] for n in tar.getnames() if "/" in n}
    assert not sorted(_tree_modules() - in_sdist)


def _run(user_venv, cwd, *argv, timeout=600):
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env.update(SDL_VIDEODRIVER="dummy", SDL_AUDIODRIVER="dummy", MPLBACKEND="Agg", OMP_NUM_THREADS="1",
               OPENBLAS_NUM_THREADS="1")
    proc = subprocess.run([str(user_venv / "bin" / argv[0]), *argv[1:]], capture_output=True, text=True,
                          cwd=cwd, env=env, timeout=timeout)
    assert proc.returncode == 0, f"{' '.join(argv)}\n{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}"
    return proc


def test_installed_tool_comes_from_the_wheel(user_venv, tmp_path):
    proc = _run(user_venv, tmp_path, "python", "-c", "import identify, signaldesign; print(identify.__file__)")
    assert str(user_venv) in proc.stdout and str(ROOT) not in proc.stdout


@pytest.mark.parametrize("method", METHOD_NAMES)
def test_every_method_from_the_wheel(user_venv, tmp_path, method):
    _run(user_venv, tmp_path, "identify", "estimate", "--profile", str(EX / "profile.toml"), "--method", method,
         str(EX / "run_lon.csv"), str(EX / "run_lat.csv"), "--out", str(tmp_path / method))
    assert (tmp_path / method / "result.json").exists()


RUNS = [str(EX / "run_lon.csv"), str(EX / "run_lat.csv")]
REAL = EX / "real_data"
# each chain a test of its own, so that the test workers share them; a chain's later commands read
# what its earlier ones wrote
CHAINS = {
    "refine": [["identify", "refine", "--profile", str(EX / "profile.toml"), *RUNS, "--max-steps", "1",
                "--out", "refine"]],
    "compat": [["identify", "compat", str(REAL / "de3211.mat"), "--channel-map", str(REAL / "matrix_map.json"),
                "--out", "compat"]],
    "freq": [["identify", "freq", "--profile", "s61_hover_4dof", *RUNS, "--out", "freq"]],
    "hq": [["identify", "hq", "--profile", "navion_cruise_long", "--n-alpha", "11.05", "--out", "hq"]],
    "design_fly": [["signaldesign", "design", "--profile", str(EX / "profile.toml"), "--input", "theta_s",
                    "--duration", "4", "--criterion", "nominal", "--jobs", "1", "--out", "sig.json"],
                   ["cueing", "fly", "--signal", "sig.json", "--source", "pilot", "--headless", "--fast",
                    "--simulate", str(EX / "truth.toml"), "--profile", str(EX / "profile.toml"), "--out", "tp.csv"]],
    "campaign": [["campaign", "synthetic", "--out", "camp", "--points", "2", "--runs", "2", "--duration", "8"],
                 ["campaign", "identify", "camp/campaign.toml", "--out", "camp/out", "--executor", "serial",
                  "--no-progress"]],
}


@pytest.mark.parametrize("chain", CHAINS)
def test_the_other_commands_from_the_wheel(user_venv, tmp_path, chain):
    for argv in CHAINS[chain]:
        _run(user_venv, tmp_path, *argv)
    if chain == "design_fly":
        assert (tmp_path / "tp.csv").exists()

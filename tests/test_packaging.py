"""Packaging and command-line niceties: one version everywhere, quiet on a closed pipe, runs not
taken by a list option."""
import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

import cueing
import identify
import signaldesign

ROOT = Path(__file__).resolve().parent.parent


def _run(args, **kw):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run(args, capture_output=True, text=True, env=env, cwd=ROOT, **kw)


def test_one_version_everywhere():
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert pyproject["project"]["dynamic"] == ["version"]
    assert pyproject["tool"]["setuptools"]["dynamic"]["version"]["attr"] == "identify._version.__version__"
    assert re.fullmatch(r"\d+\.\d+\.\d+", identify.__version__)
    assert cueing.__version__ == signaldesign.__version__ == identify.__version__
    assert f"## {identify.__version__}" in (ROOT / "CHANGELOG.md").read_text()
    # SPDX license strings need setuptools >= 77
    assert any(r.startswith("setuptools>=") and int(r.split(">=")[1].split(".")[0]) >= 77
               for r in pyproject["build-system"]["requires"])


@pytest.mark.parametrize("argv", [["identify"], ["signaldesign"], ["cueing"], ["identify", "estimate"],
                                  ["signaldesign", "design"], ["cueing", "fly"]])
def test_version_on_every_command(argv):
    proc = _run([sys.executable, "-m", *argv, "--version"])
    assert proc.returncode == 0 and proc.stdout.strip() == f"{argv[0]} (pseudostep) {identify.__version__}"


def test_closed_pipe_is_quiet():
    proc = _run(["bash", "-c", f"{sys.executable} -m identify model s61_hover_8state | head -1"])
    assert proc.returncode == 0 and proc.stderr == "" and proc.stdout.startswith("S 61")


def test_list_option_before_runs_says_why():
    proc = _run([sys.executable, "-m", "identify", "refine", "--profile", "examples/profile.toml", "--validate",
                 "examples/val_1.csv", "examples/run_lon.csv", "--out", "never"])
    assert proc.returncode == 2 and "--validate takes every file after it: put it after the runs" in proc.stderr
    assert not (ROOT / "never").exists()


def test_estimate_writes_summary_and_result_reads_back(tmp_path):
    from identify import IdentificationResult
    from identify.estimators.plots import save_plots
    proc = _run([sys.executable, "-m", "identify", "estimate", "--profile", "examples/profile.toml", "--method", "ls",
                 "examples/run_lon.csv", "examples/run_lat.csv", "--out", str(tmp_path)])
    assert proc.returncode == 0, proc.stderr
    summary = (tmp_path / "summary.txt").read_text()
    assert summary.startswith("LS identification of") and "M_theta_s" in summary and "mean" in summary
    back = IdentificationResult.from_json(tmp_path / "result.json")
    assert back.summary().splitlines()[:22] == summary.splitlines()[:22]  # the parameter table, as printed
    assert len(back.time) == 2 and back.measured[0].shape == back.modelled[0].shape
    assert [p.name for p in save_plots(back, tmp_path / "again")] == ["time_history_run1.png", "time_history_run2.png",
                                                                        "residuals.png"]


def test_model_prints_declared_delays():
    proc = _run([sys.executable, "-m", "identify", "model", "examples/truth.toml"])
    assert proc.returncode == 0
    assert "delay on theta_s: 0.08 s" in proc.stdout and "delay on theta_c: 0.08 s" in proc.stdout
    plain = _run([sys.executable, "-m", "identify", "model", "examples/profile.toml"])
    assert "declared effects (every command applies them to the runs): none" in plain.stdout


def test_fix_and_outputs_options(tmp_path):
    proc = _run([sys.executable, "-m", "identify", "estimate", "--profile", "examples/profile.toml", "--method", "ls",
                 "examples/run_lon.csv", "examples/run_lat.csv", "--fix", "M_q,L_p", "--out", str(tmp_path)])
    assert proc.returncode == 0, proc.stderr
    assert "--fix M_q,L_p: 18 free parameters" in proc.stderr
    summary = (tmp_path / "summary.txt").read_text()
    assert "\nM_q " not in summary and "\nM_p " in summary
    bad = _run([sys.executable, "-m", "identify", "refine", "--profile", "examples/profile.toml", "examples/run_lon.csv",
                "--outputs", "p,nz", "--out", str(tmp_path / "r")])
    assert bad.returncode == 2 and "output(s) nz not in the profile" in bad.stderr

"""Small helpers for tests: running the command lines in a subprocess."""
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def run_cli(package: str, *args, cwd=None, timeout=300):
    """Run ``python -m package args`` and return the CompletedProcess (text output)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT), SDL_VIDEODRIVER="dummy", SDL_AUDIODRIVER="dummy",
               MPLBACKEND="Agg")
    return subprocess.run([sys.executable, "-m", package, *map(str, args)], capture_output=True, text=True,
                          cwd=cwd or ROOT, env=env, timeout=timeout)


def one_error_line(proc, *needles):
    """Assert exit status 2 and exactly one stderr line mentioning every needle; no traceback."""
    lines = [l for l in proc.stderr.splitlines() if l.strip()]
    assert proc.returncode == 2, (proc.returncode, proc.stderr)
    assert len(lines) == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    return lines[0]

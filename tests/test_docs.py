"""The documents cannot drift: every ```sh block of README.md and docs/*.md preceded by the line
``<!-- run -->`` is run here, one command per line (a trailing ``\\`` continues it), from a
temporary folder holding a copy of ``examples/`` (outputs land there), with ``python`` and
``.venv/bin/python`` this interpreter. A command that exits non-zero fails its block's test with
the command and its output. Each block runs in its own folder: a block may use its own earlier
commands' outputs, never another block's."""
from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
MARK = "<!-- run -->"
DOCUMENTS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
TIMEOUT = 120  # s per command: a hung command fails instead of stalling the suite


def marked_blocks(path: Path) -> list[tuple[int, list[str]]]:
    """(line number, commands) of every marked ```sh block of ``path``."""
    lines = path.read_text().splitlines()
    blocks = []
    for i, line in enumerate(lines):
        if line.strip() != MARK:
            continue
        if i + 1 >= len(lines) or lines[i + 1].strip() != "```sh":
            raise AssertionError(f"{path.name}:{i + 1}: {MARK} must be followed by a ```sh block")
        body = []
        for j in range(i + 2, len(lines)):
            if lines[j].strip() == "```":
                break
            body.append(lines[j])
        else:
            raise AssertionError(f"{path.name}:{i + 2}: unterminated ```sh block")
        blocks.append((i + 3, commands(body)))
    return blocks


def commands(body: list[str]) -> list[str]:
    """Join continuation lines (a trailing backslash, or a quote still open); drop blank and
    comment-only lines."""
    out, current = [], ""
    for line in body:
        current += line.rstrip()
        if current.endswith("\\"):
            current = current[:-1] + " "
            continue
        try:
            shlex.split(current, comments=True)
        except ValueError:  # an open quote: the command goes on
            current += "\n"
            continue
        if current.strip() and not current.strip().startswith("#"):
            out.append(current.strip())
        current = ""
    assert not current.strip(), f"unterminated command: {current!r}"
    return out


def _cases():
    """One test per marked block (each in its own folder: a block must not need another's output)."""
    for doc in DOCUMENTS:
        for line, cmds in marked_blocks(doc):
            yield pytest.param(doc, line, cmds, id=f"{doc.relative_to(ROOT).as_posix()}:{line}")


def test_marker_finds_blocks(tmp_path):
    text = f"x\n{MARK}\n```sh\npython -m a \\\n   --b c   # note\n# only a comment\n\npython -m d\n```\n"
    doc = tmp_path / "probe.md"
    doc.write_text(text)
    (line, cmds), = marked_blocks(doc)
    assert line == 4 and [" ".join(c.split()) for c in cmds] == ["python -m a --b c # note", "python -m d"]
    assert any(marked_blocks(d) for d in DOCUMENTS), "no marked block in README.md or docs/"


@pytest.mark.parametrize("doc, line, cmds", list(_cases()))
def test_document_commands_run(doc, line, cmds, tmp_path):
    shutil.copytree(ROOT / "examples", tmp_path / "examples")
    bin_dir = tmp_path / ".venv" / "bin"
    bin_dir.mkdir(parents=True)
    # a wrapper, not a symlink: a symlinked interpreter outside its venv would lose the venv
    (bin_dir / "python").write_text(f'#!/bin/sh\nexec "{sys.executable}" "$@"\n')
    (bin_dir / "python").chmod(0o755)
    env = dict(os.environ, PATH=f"{bin_dir}{os.pathsep}{os.environ['PATH']}",
               PYTHONPATH=f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}",
               SDL_VIDEODRIVER="dummy", SDL_AUDIODRIVER="dummy", MPLBACKEND="Agg",
               OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    for cmd in cmds:
        t0 = time.perf_counter()
        proc = subprocess.run(["bash", "-c", cmd], cwd=tmp_path, env=env, capture_output=True, text=True,
                              timeout=TIMEOUT)
        print(f"{time.perf_counter() - t0:6.1f} s  {cmd[:100]}")
        assert proc.returncode == 0, (f"{doc.name} (block at line {line}): `{cmd}` exited "
                                      f"{proc.returncode}\n{proc.stdout[-2000:]}\n{proc.stderr[-2000:]}")


def test_commands_name_existing_files():
    """Unmarked blocks are not run, but every file path they name under examples/ must exist."""
    missing = []
    for doc in DOCUMENTS:
        for name in re.findall(r"\bexamples/[\w./-]+\w", doc.read_text()):
            if not (ROOT / name).exists():
                missing.append(f"{doc.name}: {name}")
    assert not missing, "documents name example files that do not exist: " + ", ".join(missing)


def test_api_example_runs():
    """examples/api.py: design -> fly -> estimate -> refine through the Python API."""
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", MPLBACKEND="Agg")
    proc = subprocess.run([sys.executable, str(ROOT / "examples" / "api.py")], capture_output=True, text=True,
                          env=env, timeout=TIMEOUT)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "ML identification of" in proc.stdout and "refine added a " in proc.stdout

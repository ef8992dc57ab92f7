"""The documents cannot drift: every ```sh block of README.md and docs/*.md preceded by the line
``<!-- run -->`` is run here, one command per line (a trailing ``\\`` continues it), from a
temporary folder holding a copy of ``examples/`` (outputs land there), with ``python`` and
``.venv/bin/python`` this interpreter. A command that exits non-zero fails its block's test with
the command and its output. Blocks of one file run in order in one folder, so a later block may use
an earlier one's output (``sig.json``)."""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
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
    """Join continuation lines; drop blank and comment-only lines."""
    out, current = [], ""
    for line in body:
        current += line.rstrip()
        if current.endswith("\\"):
            current = current[:-1] + " "
            continue
        if current.strip() and not current.strip().startswith("#"):
            out.append(current.strip())
        current = ""
    return out


def _cases():
    for doc in DOCUMENTS:
        blocks = marked_blocks(doc)
        if blocks:
            yield pytest.param(doc, blocks, id=doc.relative_to(ROOT).as_posix())


def test_marker_finds_blocks():
    text = f"x\n{MARK}\n```sh\npython -m a \\\n   --b c   # note\n# only a comment\n\npython -m d\n```\n"
    doc = Path(__file__).with_name("_marker_probe.md")
    try:
        doc.write_text(text)
        assert marked_blocks(doc) == [(4, ["python -m a    --b c   # note", "python -m d"])]
    finally:
        doc.unlink()
    assert any(marked_blocks(d) for d in DOCUMENTS), "no marked block in README.md or docs/"


@pytest.mark.parametrize("doc, blocks", list(_cases()))
def test_document_commands_run(doc, blocks, tmp_path):
    shutil.copytree(ROOT / "examples", tmp_path / "examples")
    bin_dir = tmp_path / ".venv" / "bin"
    bin_dir.mkdir(parents=True)
    (bin_dir / "python").symlink_to(sys.executable)
    env = dict(os.environ, PATH=f"{bin_dir}{os.pathsep}{os.environ['PATH']}",
               PYTHONPATH=f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}",
               SDL_VIDEODRIVER="dummy", SDL_AUDIODRIVER="dummy", MPLBACKEND="Agg",
               OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    for line, cmds in blocks:
        for cmd in cmds:
            proc = subprocess.run(["bash", "-o", "pipefail", "-c", cmd], cwd=tmp_path, env=env,
                                  capture_output=True, text=True, timeout=TIMEOUT)
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

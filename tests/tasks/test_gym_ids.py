"""metadagger's Gymnasium ids, used as the README and the docs use them (docs/carracing.md shows one)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
BLOCK = re.compile(r"```python\n(.*?)```", re.S)
MAKE = re.compile(r'^[^#]*gym\.make\("metadagger/', re.M)


def _blocks_calling_gym_make() -> list[tuple[str, str]]:
    """Every Python block of the README and docs whose code (not a comment) calls gym.make on a metadagger id."""
    found = []
    for page in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        found += [(page.name, block) for block in BLOCK.findall(page.read_text()) if MAKE.search(block)]
    return found


def test_every_doc_block_that_makes_a_metadagger_id_registers_the_ids_first():
    blocks = _blocks_calling_gym_make()
    assert blocks, "docs/carracing.md shows gym.make on a metadagger id"
    for page, block in blocks:
        code = block.split("\n")
        first_make = next(i for i, line in enumerate(code) if MAKE.search(line))
        assert any("metadagger.register_envs()" in line for line in code[:first_make]), page


def test_the_carracing_page_block_runs_as_written_in_a_fresh_process():
    [(page, block)] = [(p, b) for p, b in _blocks_calling_gym_make() if p == "carracing.md"]
    # a fresh interpreter: nothing registered by other tests
    done = subprocess.run([sys.executable, "-c", block + "\nprint(obs.shape)"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip().endswith("(96, 96, 3)")


def test_importing_metadagger_registers_nothing():
    code = "import gymnasium as gym, metadagger; print(any(i.startswith('metadagger/') for i in gym.registry))"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0 and done.stdout.strip() == "False", done.stderr[-2000:]

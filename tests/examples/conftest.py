"""Gate plug-ins as if installed: a distribution's entry points written where ``pip install`` would.

A test does not install a package; it writes what installing it writes for its entry points, a
``dist-info`` folder with an ``entry_points.txt``, into a folder on ``sys.path`` (the worker
processes inherit it), and lets the gate registry load its plug-ins again; the registry is
restored afterwards.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Iterator

import pytest
from plugin_kit import install_metadata

import metadagger.imitation.gate_registry as registry


@pytest.fixture
def plugins(monkeypatch, tmp_path) -> Iterator[Callable[[str, dict[str, str]], Path]]:
    """``install(name, entry_points)``: a distribution with those gate entry points, as if installed;
    the registry then loads the installed plug-ins again, and is restored after the test."""
    monkeypatch.setattr(registry, "_GATES", dict(registry._GATES))
    monkeypatch.setattr(registry, "_plugins_loaded", False)

    def install(name: str, entry_points: dict[str, str]) -> Path:
        site = tmp_path / f"site-{name}"
        install_metadata(site, name, entry_points)
        monkeypatch.syspath_prepend(str(site))
        return site

    yield install

"""Finished artifacts shared by the run folders of one machine, each under the stamp it was made from.

An artifact that depends on nothing but its stamp (pi*: the task it learns, its config and the
numerics) is looked up here before it is computed, and kept here once it is. A run folder that
takes one copies its files and records where they were made, so it holds what computing them would
have written, byte for byte. ``METADAGGER_CACHE`` moves the cache (default
``$XDG_CACHE_HOME/metadagger``, else ``~/.cache/metadagger``); ``METADAGGER_CACHE=off`` turns it
off. It is off too while metadagger's own source has uncommitted changes: the key is the stamp,
which a change of the code that makes an artifact does not reach until it bumps ``NUMERICS``, so
code being changed neither takes nor keeps.

An entry is a folder ``KIND/KEY`` (KEY: a hash of the stamp) holding the files, ``stamp.json``
(checked on every read, so a hash that collides or an entry of another stamp is never taken) and
``made.json`` (where and when it was made). It is written whole or not at all; one that does not
read is passed over and written again. The cache never stops a run: a cache that cannot be
written is one warning line, and the run keeps its own artifacts.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
from pathlib import Path
from typing import Any, Mapping

from metadagger.errors import UserError
from metadagger.runfolder.stamps import canonical, data_fingerprint
from metadagger.utils.io import atomic_folder, write_json
from metadagger.version import source_revision

CACHE_ENV = "METADAGGER_CACHE"
"""The environment variable that names the cache's folder, or ``off``."""
OFF = "off"
STAMP_FILE = "stamp.json"
MADE_FILE = "made.json"


def cache_root() -> Path | None:
    """The cache's folder, or None when ``METADAGGER_CACHE=off`` or metadagger's source tree has
    uncommitted changes."""
    value = os.environ.get(CACHE_ENV, "").strip()
    if value.lower() == OFF or source_revision().endswith("+dirty"):
        return None
    if value:
        return Path(value).expanduser()
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "metadagger"


def entry_folder(kind: str, stamp: Mapping[str, Any]) -> Path | None:
    """Where the entry of ``kind`` made from ``stamp`` lives (whether or not it exists); None when
    the cache is off."""
    root = cache_root()
    return None if root is None else root / kind / data_fingerprint(stamp)


def cached(kind: str, stamp: Mapping[str, Any], names: tuple[str, ...]) -> Path | None:
    """The entry of ``kind`` made from ``stamp`` holding every file of ``names``, or None: the cache
    is off, holds none, or holds one whose stamp or record does not read as this one."""
    folder = entry_folder(kind, stamp)
    return folder if folder is not None and _holds(folder, stamp, names) else None


def _holds(folder: Path, stamp: Mapping[str, Any], names: tuple[str, ...]) -> bool:
    """Whether ``folder`` is a whole entry made from ``stamp`` holding every file of ``names``."""
    if not all((folder / name).is_file() for name in (*names, STAMP_FILE, MADE_FILE)):
        return False
    try:
        recorded = json.loads((folder / STAMP_FILE).read_text())
        json.loads((folder / MADE_FILE).read_text())
    except (OSError, UnicodeDecodeError, ValueError):
        return False
    return canonical(recorded) == canonical(stamp)


def made_record(folder: Path) -> dict[str, Any]:
    """An entry's record of where it was made (:func:`keep`'s ``made``)."""
    return json.loads((folder / MADE_FILE).read_text())


def keep(kind: str, stamp: Mapping[str, Any], files: Mapping[str, Path], made: Mapping[str, Any]) -> Path | None:
    """Put ``files`` (a name in the entry to the file to copy) in the cache under ``stamp``, with
    ``made`` (JSON: where, when, how long); an entry there already is left as it is. Returns the
    entry, or None when the cache is off or cannot be written (a warning line says why)."""
    folder = entry_folder(kind, stamp)
    if folder is None or _holds(folder, stamp, tuple(files)):
        return folder

    def write(staging: Path) -> None:
        for name, source in files.items():
            shutil.copyfile(source, staging / name)
        write_json(staging / STAMP_FILE, dict(stamp))
        write_json(staging / MADE_FILE, dict(made))

    try:
        return atomic_folder(folder, write)
    except (OSError, UserError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        print(
            f"warning: could not keep {kind} in the cache {folder} ({reason}); the run goes on without it: "
            f"set {CACHE_ENV} to a folder you can write to, or {CACHE_ENV}={OFF}",
            file=sys.stderr,
            flush=True,
        )
        return None

"""Plumbing any layer may import: atomic files, JSON-lines logs, progress bars, plots, the CPU
kernel pin, the executors and their Ray connection, and the YAML -> dataclass builder.

Nothing here imports another part of metadagger except :mod:`metadagger.errors` and
:mod:`metadagger.version`.
"""

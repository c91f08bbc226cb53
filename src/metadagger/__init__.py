"""metadagger: Meta-Learning DAgger (MetaL DAgger) for imitation-learning research.

Importing the package selects the same CPU kernels on every x86-64 machine
(:mod:`metadagger.utils.kernels`) and registers its Gymnasium ids. The public interface::

    task = metadagger.make_task("carracing")
    policy = metadagger.load_policy(path)
    mapper = metadagger.load_mapper(path)
"""

from __future__ import annotations

from metadagger.utils.kernels import pin_cpu_kernels

pin_cpu_kernels()  # before any tensor operation (docs/architecture.md, "Determinism")

from metadagger.errors import CheckpointError, UserError  # noqa: E402
from metadagger.tasks import make_task, register_task  # noqa: E402
from metadagger.tasks.gym_ids import register_envs  # noqa: E402

from metadagger.version import __version__  # noqa: E402

register_envs()


def load_policy(path):
    """Rebuild a saved policy (see :func:`metadagger.policies.load_policy`)."""
    from metadagger.policies import load_policy as _load

    return _load(path)


def load_mapper(path):
    """Rebuild a saved mapper (see :func:`metadagger.mapping.mappers.load_mapper`)."""
    from metadagger.mapping.mappers import load_mapper as _load

    return _load(path)


__all__ = ["CheckpointError", "UserError", "__version__", "load_mapper", "load_policy", "make_task", "register_task"]

"""metadagger: Meta-Learning DAgger (MetaL DAgger) for imitation-learning research.

Importing the package changes nothing in the process: the Gymnasium ids are registered when a
task or one of its envs is made (:func:`~metadagger.tasks.gym_ids.register_envs`), and the CPU
kernels are pinned by whoever asks (:func:`pin_cpu_kernels`: the command line, the pipeline's
entry points, the executors' workers). The public interface::

    metadagger.pin_cpu_kernels()          # the command line's kernels; before any tensor operation
    task = metadagger.make_task("carracing")
    policy = metadagger.load_policy(path)
    mapper = metadagger.load_mapper(path)
"""

from __future__ import annotations

from metadagger.errors import CheckpointError, UserError
from metadagger.tasks import make_task, register_task
from metadagger.tasks.gym_ids import register_envs
from metadagger.utils.kernels import pin_cpu_kernels
from metadagger.version import __version__


def load_policy(path):
    """Rebuild a saved policy (see :func:`metadagger.policies.load_policy`)."""
    from metadagger.policies import load_policy as _load

    return _load(path)


def load_mapper(path):
    """Rebuild a saved mapper (see :func:`metadagger.mapping.mappers.load_mapper`)."""
    from metadagger.mapping.mappers import load_mapper as _load

    return _load(path)


__all__ = ["CheckpointError", "UserError", "__version__", "load_mapper", "load_policy", "make_task", "pin_cpu_kernels",
           "register_envs", "register_task"]

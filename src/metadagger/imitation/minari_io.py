"""Episodes to and from Minari datasets, Farama's standard for offline data.

A written dataset holds, per episode, the observations (``T + 1``, the last one never acted on),
the action the learner took, the env's rewards, terminations and truncations, and per observation
in ``infos``: the expert's label (``expert_label``), whether it was queried (``queried``: labels
kept for training; the final observation's label is computed by the env but never trained on), the
DAgger round (``round``: 0 is the expert's demonstration) and the env seed (``seed``).
Images are stored losslessly (no JPEG), so a dataset read back equals what was written.

Reading takes any Minari dataset whose spaces match the task's learner: with ``expert_label`` in
its infos, the queried states and their labels; otherwise each observation with the action taken
(a dataset of expert demonstrations).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Iterator

import gymnasium as gym
import numpy as np

from metadagger.errors import UserError
from metadagger.imitation.data import Dataset
from metadagger.imitation.rollouts import Trajectory, stack_labels
from metadagger.utils.io import atomic_folder

INSTALL_MINARI = 'pip install -c constraints.txt -e ".[minari]"'


@dataclass(frozen=True)
class RecordedEpisode:
    """One episode and where it came from."""

    trajectory: Trajectory
    round: int
    """0: the expert's demonstration; k: the rollout of DAgger round k."""
    queried: np.ndarray | None = None
    """(T,) bool: which states' labels were kept for training; None: every state's."""


def _minari() -> Any:
    try:
        import minari
    except ImportError:
        raise UserError(f"Minari is not installed; install it with `{INSTALL_MINARI}`") from None
    return minari


def datasets_root() -> Path:
    """Where Minari keeps local datasets (``MINARI_DATASETS_PATH``, default ``~/.minari/datasets``)."""
    return Path(os.environ.get("MINARI_DATASETS_PATH", Path.home() / ".minari" / "datasets"))


def check_new_dataset_name(name: str) -> None:
    """Raise a :class:`UserError` unless ``name`` is a valid Minari id that no local dataset uses."""
    _minari()  # first: a missing package is a UserError, not an ImportError below
    from minari.dataset.minari_dataset import parse_dataset_id

    try:
        parse_dataset_id(name)
    except (ValueError, TypeError):  # TypeError: Minari 0.5 fails so on a name without -v<version>
        raise UserError(
            f"--name {name!r} is not a Minari dataset id; expected (namespace/)name-v<version> with a "
            "namespace of 2 or more characters, e.g. metadagger/carracing-demos-v0"
        ) from None
    if (datasets_root() / name).exists():
        raise UserError(
            f"a Minari dataset named {name!r} already exists in {datasets_root()}; pick another --name "
            f"(or bump its version) or delete it with `minari delete {name}`"
        )


def episode_buffer(episode: RecordedEpisode, index: int) -> Any:
    """The Minari ``EpisodeBuffer`` of ``episode`` (its id ``index``)."""
    from minari.data_collector import EpisodeBuffer

    traj = episode.trajectory
    steps = traj.steps
    discrete = traj.expert_labels.dtype == np.int64
    queried = np.ones(steps, dtype=bool) if episode.queried is None else np.asarray(episode.queried, dtype=bool)
    if queried.shape != (steps,):
        raise ValueError(f"queried has shape {queried.shape}, expected ({steps},) for an episode of {steps} steps")
    infos = {
        "expert_label": np.concatenate([traj.expert_labels, stack_labels([traj.final_label], discrete)]),
        "queried": np.append(queried, False),
        "round": np.full(steps + 1, episode.round, dtype=np.int64),
        "seed": np.full(steps + 1, traj.seed, dtype=np.int64),
    }
    last = steps - 1
    return EpisodeBuffer(
        id=index,
        seed=traj.seed,
        observations=np.concatenate([traj.obs, traj.final_obs[None]]),
        actions=traj.learner_actions,
        rewards=[float(r) for r in traj.step_rewards],
        terminations=[i == last and traj.terminated for i in range(steps)],
        truncations=[i == last and not traj.terminated for i in range(steps)],
        infos=infos,
    )


def write_dataset(
    name: str,
    chunks: Iterable[list[RecordedEpisode]],
    *,
    observation_space: gym.Space,
    action_space: gym.Space,
    description: str,
    algorithm: str,
    author: str,
    author_email: str | None,
    code_permalink: str,
) -> Path:
    """Write the episodes of ``chunks`` (in order) as the Minari dataset ``name``, with its
    provenance: ``algorithm``, ``author`` (and ``author_email`` where given) and ``code_permalink``.

    The dataset is built in a staging folder beside the datasets and renamed into place when the
    last chunk is written, so a killed export leaves no half-written dataset under ``name``.

    Returns:
        The dataset's folder.
    """
    minari = _minari()
    from minari.dataset.minari_storage import MinariStorage
    from minari.namespace import create_namespace, list_local_namespaces

    check_new_dataset_name(name)
    root = datasets_root()
    namespace = name.rsplit("/", 1)[0] if "/" in name else None
    if namespace is not None and namespace not in list_local_namespaces():
        create_namespace(namespace)

    def write(folder: Path) -> None:
        storage = MinariStorage.new(
            folder / "data",
            observation_space=observation_space,
            action_space=action_space,
            data_format="hdf5",
            jpeg_encoding=False,
        )
        storage.update_metadata(
            {
                "dataset_id": name,
                "algorithm_name": algorithm,
                "description": description,
                "author": {author},
                **({} if author_email is None else {"author_email": {author_email}}),
                "code_permalink": code_permalink,
                "minari_version": minari.__version__,
            }
        )
        index = 0
        for chunk in chunks:
            storage.update_episodes([episode_buffer(e, index + i) for i, e in enumerate(chunk)])
            index += len(chunk)

    # staged in the datasets root (a hidden folder Minari does not list), renamed into place when complete
    return atomic_folder(root / name, write, staging_in=root)


def _same_space(a: gym.Space, b: gym.Space) -> bool:
    if isinstance(a, gym.spaces.Discrete) and isinstance(b, gym.spaces.Discrete):
        return int(a.n) == int(b.n)
    if isinstance(a, gym.spaces.Box) and isinstance(b, gym.spaces.Box):
        return a.shape == b.shape and a.dtype == b.dtype
    return False


def _episodes(dataset: Any, name: str) -> Iterator[Any]:
    """The episodes of the Minari ``dataset`` named ``name``; data files that cannot be read (a
    truncated or damaged download or export) are a :class:`UserError` naming them."""
    try:
        yield from dataset.iterate_episodes()
    except Exception as err:  # h5py and pyarrow raise several types for damaged files
        reason = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise UserError(
            f"Minari dataset {name!r} is damaged: its data in {dataset.storage.data_path} cannot be read ({reason}); "
            f"download or export it again (delete this copy first with `minari delete {name}`)"
        ) from None


def read_demonstrations(name: str, *, observation_space: gym.Space, action_space: gym.Space) -> Dataset:
    """The (observation, expert label) rows of the Minari dataset ``name``.

    Raises:
        UserError: the dataset is missing or its data cannot be read, or its spaces differ from the learner's.
    """
    minari = _minari()
    try:
        dataset = minari.load_dataset(name)
    except (FileNotFoundError, ValueError) as err:
        reason = str(err).split(". Use download=True")[0]  # the library's hint names an argument the CLI has not got
        raise UserError(
            f"cannot load Minari dataset {name!r} from {datasets_root()} ({reason}); list the local ones with "
            "`minari list local`, download it with `minari download NAME`, or set MINARI_DATASETS_PATH"
        ) from None
    for what, theirs, ours in (
        ("observation", dataset.observation_space, observation_space),
        ("action", dataset.action_space, action_space),
    ):
        if not _same_space(theirs, ours):
            raise UserError(
                f"Minari dataset {name!r} has {what} space {theirs}, but the task's learner has {ours}; "
                "use a dataset of a task with the same spaces"
            )
    discrete = isinstance(action_space, gym.spaces.Discrete)
    obs, labels = [], []
    for episode in _episodes(dataset, name):
        infos = episode.infos or {}
        if "expert_label" in infos:
            keep = np.asarray(infos["queried"], dtype=bool)[:-1] if "queried" in infos else slice(None)
            obs.append(np.asarray(episode.observations[:-1])[keep])
            labels.append(stack_labels(np.asarray(infos["expert_label"])[:-1][keep], discrete))
        else:
            obs.append(np.asarray(episode.observations[:-1]))
            labels.append(stack_labels(np.asarray(episode.actions), discrete))
    if not obs:
        raise UserError(f"Minari dataset {name!r} has no episodes; export or collect some first")
    return Dataset(obs=np.concatenate(obs).astype(np.uint8, copy=False), labels=np.concatenate(labels))

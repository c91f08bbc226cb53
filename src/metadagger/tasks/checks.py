"""Checks of a task's code: what metadagger needs from a :class:`~metadagger.tasks.base.Task`.

:func:`check_task_code` is the cheap part (one env, a few steps, about a second): the observation
space (uint8 images, height x width x channels, few channels), the learner's action space, that
the expert's labels are valid learner actions, that ``combine`` and ``to_label`` agree, and that
the seed draws the whole episode. ``reproduce``, ``pistar`` and ``pairs`` run it before any
work; ``metadagger check-task`` runs it and then measures the expert on seeds. Every problem is a
:class:`~metadagger.errors.UserError` naming the Task method, the value seen and what is expected.
"""

from __future__ import annotations

import functools
from typing import Any, Callable

import gymnasium as gym
import numpy as np

from metadagger.errors import UserError
from metadagger.tasks.base import Task

#: Most image channels an observation may have (RGB, RGBA, gray).
MAX_CHANNELS = 4
#: Steps the determinism check drives two envs of one seed with the expert.
DETERMINISM_STEPS = 5
#: Most classes of a Discrete action space whose combine/to_label round trip is checked one by one.
MAX_CHECKED_CLASSES = 64


def _call(task: Task, method: str, fn: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
    """``fn(*args)``, an exception in it becoming one line naming ``method`` of the task's class."""
    try:
        return fn(*args, **kwargs)
    except UserError:
        raise
    except Exception as exc:  # the task's own code: any mistake in it is the user's to fix
        raise UserError(
            f"{_where(task, method)} raised {type(exc).__name__}: {exc}; fix the task's code "
            f"(`metadagger check-task --task {task.name}` checks it)"
        ) from None


def _where(task: Task, method: str) -> str:
    return f"{type(task).__name__}.{method}"


def check_observation_space(task: Task, space: gym.Space) -> None:
    """The observation space is a uint8 ``Box`` of shape (height, width, channels), channels 1-4."""
    where = _where(task, "make_base_env")
    if not isinstance(space, gym.spaces.Box):
        raise UserError(
            f"{where}: the env's observation_space is {space}; expected a Box of uint8 images (H, W, C); "
            "wrap the env so that it returns rendered frames (see docs/custom_task.md)"
        )
    shape = tuple(space.shape)
    if len(shape) != 3:
        raise UserError(
            f"{where}: the env's observations have shape {shape}; expected images (H, W, C), e.g. (64, 64, 3); "
            "metadagger learns from pixels: render frames in an ObservationWrapper"
        )
    if space.dtype != np.uint8:
        raise UserError(
            f"{where}: the env's observations are {space.dtype}; expected uint8 pixels 0-255; "
            "scale float images in [0, 1] with (obs * 255).round().astype(np.uint8) in an ObservationWrapper"
        )
    if not 1 <= shape[2] <= MAX_CHANNELS:
        first = (
            " (it looks channels-first: move the channel axis last with np.moveaxis(obs, 0, -1))"
            if shape[0] <= MAX_CHANNELS
            else ""
        )
        raise UserError(
            f"{where}: the env's observations have shape {shape}; expected (H, W, C) with 1-{MAX_CHANNELS} "
            f"channels last{first}"
        )


def check_observation(task: Task, space: gym.spaces.Box, obs: Any, method: str) -> None:
    """An observation ``method`` returned matches the declared observation space."""
    array = np.asarray(obs)
    if array.dtype != space.dtype or array.shape != space.shape:
        raise UserError(
            f"{_where(task, method)}: returned an observation of {array.dtype} {array.shape}; the env's "
            f"observation_space declares {space.dtype} {tuple(space.shape)}; make them agree"
        )


def check_action_space(task: Task) -> gym.Space:
    """The learner's action space: a ``Discrete`` (class index) or a float ``Box`` (vector)."""
    space = _call(task, "learner_action_space", lambda: task.learner_action_space)
    if isinstance(space, gym.spaces.Discrete):
        if space.n < 2 or space.start != 0:
            raise UserError(
                f"{_where(task, 'learner_action_space')} is {space}; expected Discrete(n) with n >= 2 classes "
                "numbered from 0"
            )
        return space
    if isinstance(space, gym.spaces.Box) and np.issubdtype(space.dtype, np.floating) and len(space.shape) == 1:
        return space
    raise UserError(
        f"{_where(task, 'learner_action_space')} is {space}; expected Discrete(n) (a classification head) or "
        "a float Box of shape (k,) (a regression head)"
    )


def check_label(task: Task, space: gym.Space, label: Any, method: str = "to_label") -> None:
    """A label is a learner action: a class index in range (Discrete) or a finite float vector of
    the space's shape (Box; bounds are not checked, as ``combine`` may clip)."""
    where = _where(task, method)
    if isinstance(space, gym.spaces.Discrete):
        if isinstance(label, (bool, np.bool_)) or not isinstance(label, (int, np.integer)):
            shown = (
                f"{np.asarray(label).dtype} of shape {np.asarray(label).shape}"
                if hasattr(label, "shape")
                else type(label).__name__
            )
            raise UserError(
                f"{where} returned {label!r} ({shown}); expected a class index, an int in 0..{space.n - 1} "
                "(for a one-hot or float action, return int(np.argmax(...)) or int(...))"
            )
        if not 0 <= int(label) < space.n:
            raise UserError(f"{where} returned {int(label)}; expected a class index in 0..{space.n - 1}")
        return
    array = np.asarray(label)
    if array.dtype.kind not in "fiu" or array.shape != space.shape:
        raise UserError(
            f"{where} returned {array.dtype} of shape {array.shape}; expected a float vector of shape "
            f"{tuple(space.shape)} (the learner's action space)"
        )
    if not np.all(np.isfinite(array)):
        raise UserError(f"{where} returned a non-finite label {array.tolist()}; expected finite values")


def _same_label(space: gym.Space, a: Any, b: Any) -> bool:
    if isinstance(space, gym.spaces.Discrete):
        return int(a) == int(b)
    return bool(np.allclose(np.asarray(a, np.float64), np.asarray(b, np.float64), atol=1e-6))


def _labels_to_check(space: gym.Space, expert_label: Any) -> list[Any]:
    """Every class of a small Discrete space; for a Box, the expert's label (when inside the
    bounds) and a few points drawn inside them."""
    if isinstance(space, gym.spaces.Discrete):
        return list(range(min(int(space.n), MAX_CHECKED_CLASSES)))
    rng = np.random.default_rng(0)
    low, high = np.maximum(space.low, -1e3), np.minimum(space.high, 1e3)
    labels = [rng.uniform(low, high).astype(space.dtype) for _ in range(3)]
    return (
        [np.asarray(expert_label, space.dtype)] if space.contains(np.asarray(expert_label, space.dtype)) else []
    ) + labels


def check_round_trip(task: Task, space: gym.Space, action: np.ndarray) -> None:
    """``to_label(combine(label, action)) == label`` for the learner's labels."""
    for label in _labels_to_check(space, task.to_label(action)):
        full = _call(task, "combine", task.combine, label, action)
        back = _call(task, "to_label", task.to_label, np.asarray(full, np.float32))
        check_label(task, space, back)
        if not _same_label(space, back, label):
            raise UserError(
                f"{_where(task, 'combine')} and to_label disagree: to_label(combine({_show(label)}, expert action)) "
                f"is {_show(back)}; expected {_show(label)} (combine must put the learner's label into the full "
                "action so that to_label reads it back)"
            )


def _show(value: Any) -> str:
    array = np.asarray(value)
    return (
        str(int(array))
        if array.shape == () and array.dtype.kind in "iu"
        else str(np.round(array.astype(float), 6).tolist())
    )


def _expert_step(task: Task, space: gym.Space, env: gym.Env) -> tuple[np.ndarray, Any]:
    """The expert's full action for ``env``'s state and its label, both checked."""
    raw = _call(task, "expert", task.expert, env)
    try:
        action = np.asarray(raw, dtype=np.float32)
    except (TypeError, ValueError):
        raise UserError(
            f"{_where(task, 'expert')} returned {raw!r}; expected the full upstream action as numbers"
        ) from None
    if not np.all(np.isfinite(action)):
        raise UserError(
            f"{_where(task, 'expert')} returned a non-finite action {action.tolist()}; expected finite values"
        )
    label = _call(task, "to_label", task.to_label, action)
    check_label(task, space, label)
    return action, label


def _episode_start(task: Task, space: gym.Space, seed: int, steps: int) -> list[np.ndarray]:
    """The first ``steps + 1`` observations of ``seed``'s episode, the expert's labels driving."""
    env = _call(task, "make_base_env", task.make_base_env)
    try:
        obs_space = env.observation_space
        check_observation_space(task, obs_space)
        obs, _ = _call(task, "make_base_env()'s reset", env.reset, seed=seed)
        check_observation(task, obs_space, obs, "make_base_env()'s reset")
        frames = [np.asarray(obs)]
        for _ in range(steps):
            action, label = _expert_step(task, space, env)
            full = _call(task, "combine", task.combine, label, action)
            obs, _, terminated, truncated, _ = _call(task, "make_base_env()'s step", env.step, full)
            check_observation(task, obs_space, obs, "make_base_env()'s step")
            frames.append(np.asarray(obs))
            if terminated or truncated:
                break
        check_round_trip(task, space, _expert_step(task, space, env)[0])
        success = _call(task, "is_success", task.is_success, env)
        if not isinstance(success, (bool, np.bool_)):
            raise UserError(
                f"{_where(task, 'is_success')} returned {success!r} ({type(success).__name__}); expected a bool"
            )
        return frames
    finally:
        env.close()


@functools.lru_cache(maxsize=8)
def _checked(task: Task) -> None:
    space = check_action_space(task)
    first = _episode_start(task, space, seed=0, steps=DETERMINISM_STEPS)
    again = _episode_start(task, space, seed=0, steps=DETERMINISM_STEPS)
    for step, (a, b) in enumerate(zip(first, again)):
        if a.shape != b.shape or not np.array_equal(a, b):
            raise UserError(
                f"{_where(task, 'make_base_env')}: two envs reset with seed 0 differ after {step} expert steps; "
                "expected the seed to draw the whole episode: draw all randomness from reset(seed=...)'s "
                "self.np_random, never from the global random or numpy generators"
            )
    if len(first) != len(again):
        raise UserError(
            f"{_where(task, 'make_base_env')}: two envs reset with seed 0 end after {len(first) - 1} and "
            f"{len(again) - 1} expert steps; expected the seed to draw the whole episode"
        )


def check_task_code(task: Task) -> None:
    """The cheap checks of a task's code (spaces, labels, combine/to_label, determinism); raises a
    :class:`UserError` naming the Task method, the value seen and what is expected. Done once per
    task object in a process."""
    try:
        hash(task)
    except TypeError:  # an unhashable task object: checked every time
        _checked.__wrapped__(task)
    else:
        _checked(task)

"""metadagger's Gymnasium ids (entry points load lazily), registered by :func:`register_envs`.

Making a task (:func:`metadagger.tasks.make_task`) or one of its envs (:meth:`Task.make_env
<metadagger.tasks.base.Task.make_env>`) registers them; code that calls ``gym.make`` on one of these
ids first calls :func:`register_envs` (or ``metadagger.register_envs()``) itself. Importing
metadagger leaves Gymnasium's registry alone.
"""

from __future__ import annotations

import gymnasium as gym

ENV_IDS = {
    "metadagger/CarRacing-v0": "metadagger.tasks.carracing.env:CarRacingFast",
    "metadagger/CarRacingSteer-v0": "metadagger.tasks.carracing.task:make_steer_env",
    "metadagger/FetchPickAndPlacePixels-v0": "metadagger.tasks.fetch.env:FetchPickAndPlacePixels",
    "metadagger/FetchPickAndPlaceXYZ-v0": "metadagger.tasks.fetch.task:make_xyz_env",
    "metadagger/CarRacingSteerFamily-v0": "metadagger.tasks.carracing.family:make_family_env",
    "metadagger/CarRacingEcho-v0": "metadagger.tasks.carracing_echo.task:make_echo_env",
    "metadagger/FetchPickAndPlaceXYZFamily-v0": "metadagger.tasks.fetch.family:make_family_env",
}
_MAX_STEPS = {"metadagger/CarRacing-v0": 1000, "metadagger/FetchPickAndPlacePixels-v0": 50}


def register_envs() -> None:
    """Register every metadagger id once (idempotent)."""
    for env_id, entry_point in ENV_IDS.items():
        if env_id in gym.registry:
            continue
        gym.register(id=env_id, entry_point=entry_point, max_episode_steps=_MAX_STEPS.get(env_id))

"""Gymnasium ids registered when :mod:`metadagger` is imported (entry points load lazily)."""

from __future__ import annotations

import gymnasium as gym

ENV_IDS = {
    "metadagger/CarRacing-v0": "metadagger.tasks.carracing.env:CarRacingFast",
    "metadagger/CarRacingSteer-v0": "metadagger.tasks.carracing.task:make_steer_env",
    "metadagger/FetchPickAndPlacePixels-v0": "metadagger.tasks.fetch.env:FetchPickAndPlacePixels",
    "metadagger/FetchPickAndPlaceXYZ-v0": "metadagger.tasks.fetch.task:make_xyz_env",
    "metadagger/CarRacingSteerFamily-v0": "metadagger.tasks.carracing.family:make_family_env",
    "metadagger/FetchPickAndPlaceXYZFamily-v0": "metadagger.tasks.fetch.family:make_family_env",
}
_MAX_STEPS = {"metadagger/CarRacing-v0": 1000, "metadagger/FetchPickAndPlacePixels-v0": 50}


def register_envs() -> None:
    """Register every metadagger id once (idempotent)."""
    for env_id, entry_point in ENV_IDS.items():
        if env_id in gym.registry:
            continue
        gym.register(id=env_id, entry_point=entry_point, max_episode_steps=_MAX_STEPS.get(env_id))

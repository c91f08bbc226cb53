"""The overview a person sees beside a state's frame: which task has one, CarRacing's track drawn with
the car heading up, and the snapshots recorded while the learner drives."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from toy_task import CorridorTask

from metadagger.errors import UserError
from metadagger.imitation.rollouts import rollout
from metadagger.label.overview import Overview, OverviewRecorder, TrackOverview, overview_of
from metadagger.tasks.carracing.task import CarRacingTask

GRASS, ROAD, AHEAD, CAR = (88, 150, 88), (105, 105, 105), (250, 250, 250), (220, 0, 0)


class Dots(Overview):
    caption = "a dot per step"

    def snapshot(self, env):
        return 0

    def draw(self, snapshots, step):
        return np.zeros((2, 2, 3), np.uint8)


def test_carracing_has_the_track_overview_and_a_task_may_declare_its_own():
    assert isinstance(overview_of(CarRacingTask()), TrackOverview)
    assert overview_of(CorridorTask()) is None  # the page shows the frame alone

    class Own(CorridorTask):
        def person_overview(self) -> Overview:
            return Dots()

    class Wrong(CorridorTask):
        def person_overview(self):
            return "a map"

    assert isinstance(overview_of(Own()), Dots)
    with pytest.raises(UserError, match=r"person_overview\(\) must return a metadagger.label.overview.Overview"):
        overview_of(Wrong())


@pytest.mark.parametrize("angle", [0.0, 0.7, -2.5])
def test_the_track_is_turned_so_that_the_car_heads_up_and_the_road_ahead_is_white(angle):
    heading = np.array([-math.sin(angle), math.cos(angle)])  # a Box2D body's forward axis, its +y
    car = np.array([30.0, -12.0])
    line = car + np.arange(-120, 121, 4.0)[:, None] * heading  # a straight road through the car, driven forward
    snapshots = [(line, *(car - heading * 8), angle), (line, *car, angle)]
    image = TrackOverview().draw(snapshots, 1)
    middle = image.shape[0] // 2
    assert image.shape == (224, 224, 3) and image.dtype == np.uint8
    assert tuple(image[middle - 2, middle]) == CAR  # the car in the middle
    assert tuple(image[middle - 14, middle]) == AHEAD  # the road ahead of it (an eighth of the lap), up
    assert tuple(image[middle + 60, middle]) == ROAD  # the road behind it, down
    assert tuple(image[middle, middle - 40]) == GRASS and tuple(image[middle, middle + 40]) == GRASS


def test_the_recorder_keeps_a_snapshot_of_every_state_of_the_last_episode():
    task = CarRacingTask(max_episode_steps=12)
    recorder = OverviewRecorder(overview_of(task))
    env = recorder.wrap(task.make_env())
    try:
        rollout(env, seed=5000, policy=None)  # an episode before: not the one asked
        driven = rollout(env, seed=5000, policy=lambda obs: 10)
    finally:
        env.close()
    pictures = recorder.pictures(driven)
    first, last = pictures(0), pictures(driven.steps - 1)
    assert first.shape == last.shape == (224, 224, 3)
    middle = first.shape[0] // 2
    assert tuple(first[middle - 2, middle]) == CAR == tuple(last[middle - 2, middle])
    base, [episode] = env.unwrapped, pictures.args  # a snapshot per state, the one after the last step too
    assert len(episode) == driven.steps + 1 and episode[-1][1:3] == tuple(float(v) for v in base.car.hull.position)
    assert np.array_equal(episode[0][0], np.array([(x, y) for _, _, x, y in base.track]))
    shorter = dataclasses.replace(driven, steps=driven.steps - 1)
    with pytest.raises(RuntimeError, match="the last episode recorded has 12 steps, not the 11 of the rollout asked"):
        recorder.pictures(shorter)

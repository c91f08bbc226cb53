"""A run's episodes as Minari datasets: round trip, the pairs' data re-run bit for bit, reading
datasets back for BC, and bad input."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from toy_task import CorridorTask

minari = pytest.importorskip("minari")

from test_pistar_pairs import GT, PAIRS  # noqa: E402

from metadagger.errors import UserError  # noqa: E402
from metadagger.imitation.collect import collect  # noqa: E402
from metadagger.imitation.minari_io import read_demonstrations  # noqa: E402
from metadagger.metal_dagger.export import export_run  # noqa: E402
from metadagger.metal_dagger.pairs import collect_pairs, run_pair  # noqa: E402
from metadagger.metal_dagger.pistar import train_pistar  # noqa: E402
from metadagger.runfolder.driver import StageOptions  # noqa: E402
from metadagger.runfolder.layout import RunLayout  # noqa: E402

SEEDS = PAIRS.seeds[:3]
OPTIONS = StageOptions(workers=2, progress=False)


@pytest.fixture(autouse=True)
def datasets(tmp_path, monkeypatch) -> Path:
    root = tmp_path / "minari"
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(root))
    return root


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> RunLayout:
    """pi* and the pairs of SEEDS on the toy corridor."""
    layout = RunLayout(tmp_path_factory.mktemp("run"))
    train_pistar(CorridorTask(), GT, layout, progress=False)
    collect_pairs(CorridorTask(), layout, dataclasses.replace(PAIRS, seeds=SEEDS), OPTIONS)
    return layout


def _spaces(task) -> dict:
    env = task.make_env()
    env.close()
    return {"observation_space": env.observation_space, "action_space": env.action_space}


def test_demos_round_trip_every_image_and_label(run):
    task = CorridorTask()
    summary = export_run(task, run, PAIRS, content="demos", name="toy/demos-v0", seeds=SEEDS, options=OPTIONS)
    demos = collect(task, SEEDS, policy=None)
    assert summary["episodes"] == len(SEEDS) and summary["steps"] == sum(t.steps for t in demos)
    dataset = minari.load_dataset("toy/demos-v0")
    episodes = list(dataset.iterate_episodes())
    assert [int(e.infos["seed"][0]) for e in episodes] == list(SEEDS)
    for episode, demo in zip(episodes, demos):
        assert np.array_equal(episode.observations[:-1], demo.obs)  # lossless images
        assert np.array_equal(episode.observations[-1], demo.final_obs)
        assert np.array_equal(episode.infos["expert_label"][:-1], demo.expert_labels)
        assert np.array_equal(episode.actions, demo.learner_actions)  # the expert acted
        assert episode.infos["queried"][:-1].all() and not episode.infos["queried"][-1]
        assert (episode.infos["round"] == 0).all()
        assert np.allclose(episode.rewards, demo.step_rewards) and bool(episode.terminations[-1]) == demo.terminated
    # provenance: the algorithm, its author and the code that made it, with no Minari warning about them
    spec = dataset.storage.metadata
    assert spec["algorithm_name"].startswith("metadagger ") and "demos: the task's expert" in spec["algorithm_name"]
    assert set(spec["author"]) == {"metadagger"} and spec["code_permalink"].startswith("metadagger ")
    # read back for BC: exactly the demonstrations' rows
    data = read_demonstrations("toy/demos-v0", **_spaces(task))
    assert np.array_equal(data.obs, np.concatenate([t.obs for t in demos]))
    assert np.array_equal(data.labels, np.concatenate([t.expert_labels for t in demos]))


def test_pairs_data_is_what_each_pair_was_fit_on(run):
    task = CorridorTask()
    summary = export_run(task, run, PAIRS, content="pairs-data", name="toy/pairs-v0", seeds=SEEDS, options=OPTIONS)
    assert summary["checked"] == len(SEEDS)  # every re-run pair equalled the stored one bit for bit
    episodes = list(minari.load_dataset("toy/pairs-v0").iterate_episodes())
    rounds = PAIRS.dagger_rounds + 1
    assert len(episodes) == len(SEEDS) * rounds
    recorded = []
    run_pair(task, str(run.pistar), SEEDS[1], PAIRS, on_episode=lambda k, t: recorded.append((k, t)))
    for episode, (round_idx, trajectory) in zip(episodes[rounds : 2 * rounds], recorded):
        assert int(episode.infos["round"][0]) == round_idx and int(episode.infos["seed"][0]) == SEEDS[1]
        assert np.array_equal(episode.observations[:-1], trajectory.obs)
        assert np.array_equal(episode.actions, trajectory.learner_actions)  # the learner's own actions
        assert np.array_equal(episode.infos["expert_label"][:-1], trajectory.expert_labels)
    # dagger alone: the learner's rollouts, no demonstrations
    export_run(task, run, PAIRS, content="dagger", name="toy/dagger-v0", seeds=SEEDS, options=OPTIONS)
    dagger = list(minari.load_dataset("toy/dagger-v0").iterate_episodes())
    assert [int(e.infos["round"][0]) for e in dagger] == [k for _ in SEEDS for k in range(1, rounds)]


def test_export_is_deterministic_across_worker_counts(run, datasets):
    task = CorridorTask()
    export_run(
        task,
        run,
        PAIRS,
        content="pairs-data",
        name="toy/a-v0",
        seeds=SEEDS,
        options=StageOptions(workers=1, progress=False),
    )
    export_run(task, run, PAIRS, content="pairs-data", name="toy/b-v0", seeds=SEEDS, options=OPTIONS)
    a, b = (list(minari.load_dataset(n).iterate_episodes()) for n in ("toy/a-v0", "toy/b-v0"))
    assert len(a) == len(b)
    for x, y in zip(a, b):
        assert np.array_equal(x.observations, y.observations) and np.array_equal(x.actions, y.actions)
        assert all(np.array_equal(x.infos[k], y.infos[k]) for k in x.infos)


def test_a_plain_minari_dataset_of_expert_actions_reads_as_demonstrations(datasets):
    from minari.data_collector import EpisodeBuffer

    obs = np.arange(4 * 2 * 2 * 3, dtype=np.uint8).reshape(4, 2, 2, 3)
    buffer = EpisodeBuffer(
        id=0,
        seed=0,
        observations=obs,
        actions=np.array([0, 2, 1], dtype=np.int64),
        rewards=[0.0] * 3,
        terminations=[False, False, True],
        truncations=[False] * 3,
    )
    space = gym.spaces.Box(0, 255, (2, 2, 3), np.uint8)
    minari.create_dataset_from_buffers(
        "plain-v0", [buffer], observation_space=space, action_space=gym.spaces.Discrete(3)
    )
    data = read_demonstrations("plain-v0", observation_space=space, action_space=gym.spaces.Discrete(3))
    assert np.array_equal(data.obs, obs[:-1]) and data.labels.tolist() == [0, 2, 1]
    with pytest.raises(UserError, match=r"action space Discrete\(3\), but the task's learner has Discrete\(5\)"):
        read_demonstrations("plain-v0", observation_space=space, action_space=gym.spaces.Discrete(5))


def test_bad_input_is_one_clear_error(run, datasets):
    task = CorridorTask()
    with pytest.raises(UserError, match="not an export; expected one of demos, dagger, pairs-data"):
        export_run(task, run, PAIRS, content="states", name="toy/x-v0", seeds=SEEDS)
    with pytest.raises(UserError, match="not a Minari dataset id"):
        export_run(task, run, PAIRS, content="demos", name="no version", seeds=SEEDS)
    export_run(task, run, PAIRS, content="demos", name="toy/taken-v0", seeds=SEEDS[:1], options=OPTIONS)
    with pytest.raises(UserError, match="already exists"):
        export_run(task, run, PAIRS, content="demos", name="toy/taken-v0", seeds=SEEDS[:1])
    with pytest.raises(UserError, match="pi\\* not found"):
        export_run(task, RunLayout(datasets / "empty"), PAIRS, content="dagger", name="toy/y-v0", seeds=SEEDS)
    with pytest.raises(UserError, match="cannot load Minari dataset 'missing-v0'"):
        read_demonstrations("missing-v0", **_spaces(task))
    assert sorted(p.name for p in datasets.rglob("*-v0")) == ["taken-v0"]  # nothing half-written


@pytest.mark.parametrize(
    "args, needle",
    [
        (
            ["--content", "states", "--name", "toy/x-v0"],
            "--content 'states' is not an export; expected one of demos, dagger, pairs-data",
        ),
        (
            ["--content", "demos", "--format", "hdf5", "--name", "toy/x-v0"],
            "--format 'hdf5' is not supported; expected one of minari",
        ),
        (["--content", "demos", "--name", "x"], "--name 'x' is not a Minari dataset id"),
        (["--content", "demos", "--name", "toy/x-v0", "--seeds", "abc"], "bad seed list 'abc'"),
    ],
)
def test_export_command_refuses_bad_input_before_any_work(tmp_path, args, needle):
    from typer.testing import CliRunner

    from metadagger.cli.main import app

    result = CliRunner().invoke(app, ["export", "--out", str(tmp_path / "no-run"), *args])
    assert result.exit_code == 2, result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and needle in lines[0], result.output

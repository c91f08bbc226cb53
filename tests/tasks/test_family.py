"""Task families: the variation is the seed's alone, acts between the command and the simulator,
never reaches the observation, and the expert compensates; a custom family (the corridor's) runs
the whole pipeline, its pi* learning the nominal member and its report showing each seed's variation."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from toy_task import TINY_PRESETS, CorridorFamily, RunCorridorTask
from typer.testing import CliRunner

from metadagger.cli.main import app
from metadagger.errors import UserError
from metadagger.metal_dagger.store import PairStore
from metadagger.policies import load_policy
from metadagger.runfolder.layout import RunLayout
from metadagger.tasks import make_task
from metadagger.tasks.base import LearnerEnv
from metadagger.tasks.carracing.expert import STEER_LIMIT
from metadagger.tasks.carracing.family import SteeringVariation
from metadagger.tasks.carracing.task import CarRacingTask
from metadagger.tasks.family import VariedEnv

runner = CliRunner()


def test_a_seed_draws_the_same_variation_every_time_and_seeds_differ():
    family = make_task("carracing-family")
    draws = [family.variation_of(seed) for seed in range(1000, 1200)]
    assert draws == [family.variation_of(seed) for seed in range(1000, 1200)]
    gains = np.array([d["gain"] for d in draws])
    offsets = np.array([d["offset"] for d in draws])
    assert len(set(gains)) == len(gains)
    assert 0.35 < np.mean(gains < 0) < 0.65  # mirrored with probability 1/2
    assert np.all((np.abs(gains) >= 0.8) & (np.abs(gains) <= 2.0)) and np.all(np.abs(offsets) <= 0.1)


def test_the_expert_compensates_exactly_where_the_command_can_reach():
    variation = SteeringVariation()
    rng = np.random.default_rng(0)
    for _ in range(50):
        v = variation.sample(rng)
        reachable = np.sort(
            np.clip(v["gain"] * np.array([-STEER_LIMIT, STEER_LIMIT]) + v["offset"], -STEER_LIMIT, STEER_LIMIT)
        )
        wanted = np.array([rng.uniform(*reachable), 0.3, 0.0], dtype=np.float32)
        command = variation.compensate(v, wanted)
        assert abs(command[0]) <= STEER_LIMIT
        np.testing.assert_allclose(variation.apply(v, command), wanted, atol=1e-6)
    assert variation.size({"gain": 1.0, "offset": 0.0}) == 0.0
    assert variation.size({"gain": -1.0, "offset": 0.0}) > variation.size({"gain": 1.5, "offset": 0.05}) > 0.0


def test_the_variation_is_in_info_never_in_the_observation():
    family, nominal = make_task("carracing-family", max_episode_steps=30), CarRacingTask(max_episode_steps=30)
    seed = next(s for s in range(1000, 1100) if family.variation_of(s)["gain"] < 0)
    env, plain = family.make_env(), nominal.make_env()
    obs, info = env.reset(seed=seed)
    plain_obs, plain_info = plain.reset(seed=seed)
    assert info["variation"] == family.variation_of(seed)
    np.testing.assert_array_equal(obs, plain_obs)  # the same image: the learner cannot see the variation
    # a mirrored car: the expert's command has the opposite sign of the nominal one
    assert (
        np.sign(info["expert_action"][0]) == -np.sign(plain_info["expert_action"][0])
        or abs(plain_info["expert_action"][0]) < 0.05
    )
    _, _, _, _, info = env.step(info["expert_label"])
    assert info["variation"] == family.variation_of(seed)
    env.close()
    plain.close()


def test_the_registered_family_env_passes_check_env():
    env = gym.make("metadagger/CarRacingSteerFamily-v0", max_episode_steps=20)
    while not isinstance(env, LearnerEnv):  # peel the checker wrappers gym.make adds
        env = env.env
    assert isinstance(env.env, VariedEnv)
    check_env(env, skip_render_check=True)
    env.close()


def test_the_expert_drives_a_lap_on_a_mirrored_car():
    from metadagger.imitation.rollouts import rollout

    family = make_task("carracing-family")
    seed = next(s for s in range(1000, 1100) if family.variation_of(s)["gain"] < -1.2)
    env = family.make_env()
    trajectory = rollout(env, seed=seed, policy=None)
    env.close()
    assert trajectory.success and trajectory.variation == family.variation_of(seed)


@pytest.mark.parametrize(
    "kwargs", [{"mirror_probability": 1.5}, {"gain_range": (2.0, 1.0)}, {"gain_range": (0.0, 1.0)}, {"max_offset": 0.5}]
)
def test_bad_variation_settings_are_user_errors(kwargs):
    with pytest.raises(UserError):
        make_task("carracing-family", **kwargs)


@pytest.fixture
def corridor_family(tmp_path):
    """The tiny presets, with the corridor family registered as a task."""
    from metadagger.tasks import _FACTORIES, register_task

    register_task("corridor-family", CorridorFamily)
    path = tmp_path / "presets.yaml"
    path.write_text(TINY_PRESETS)
    yield path
    del _FACTORIES["corridor-family"]


def test_a_custom_family_runs_the_pipeline_and_reports_each_seeds_variation(corridor_family, tmp_path):
    from metadagger.metal_dagger.pistar import train_pistar
    from metadagger.pipeline.run_config import load_run

    run = RunLayout(tmp_path / "family")
    result = runner.invoke(
        app,
        [
            "reproduce",
            "--task",
            "corridor-family",
            "--presets",
            str(corridor_family),
            "--preset",
            "tiny",
            "--out",
            str(run.root),
            "--workers",
            "1",
            "--set",
            "evaluate.methods=[dm, mean-da, pistar-head]",
            "--set",
            "mappers={dm: {epochs: 3}}",
            "--set",
            "benchmark={seeds: [300, 301], methods: [bc, mdm, dagger], grids: {}}",
        ],
    )
    assert result.exit_code == 0, result.output
    # pi* learns the nominal member: the same weights as a pi* trained on the plain corridor
    plain = RunLayout(tmp_path / "plain")
    train_pistar(RunCorridorTask(max_episode_steps=12), load_run(run.root).pistar, plain, progress=False)
    for a, b in zip(
        load_policy(run.pistar).net.state_dict().values(), load_policy(plain.pistar).net.state_dict().values()
    ):
        assert np.array_equal(a.numpy(), b.numpy())
    family = CorridorFamily(max_episode_steps=12)
    records = {r["seed"]: r for r in PairStore(run.pairs_dir).records()}
    assert records and all(r["variation"] == family.variation_of(s) for s, r in records.items())
    report = run.report.read_text()
    assert "## Task family" in report and "DAgger, 1 round |" in report
    for seed in (300, 301):
        mirror = family.variation_of(seed)["mirror"]
        assert any(line.startswith(f"| {seed} | {mirror:+.3f} |") for line in report.splitlines())
    assert (run.figures / "family_variation.png").is_file()


def test_a_plain_task_gets_no_family_section(tmp_path):
    from metadagger.evaluation.report.family import family_section
    from metadagger.evaluation.rows import write_csv

    layout = RunLayout(tmp_path)
    layout.config.write_text("task: carracing\nmax_episode_steps: 1000\n")
    rows = [{"method": "bc", "seed": 5000, "success": False, "reward": 0.0, "steps": 10, "expert_queries": 10}]
    write_csv(layout.eval_table("mdm"), rows)
    assert make_task("carracing").variation_of(5000) is None and family_section(layout) == []
    layout.config.write_text("task: carracing-family\nmax_episode_steps: 1000\n")
    assert family_section(layout)[0].startswith("## Task family")


@pytest.mark.parametrize("task", ["carracing-family", "fetch-family"])
@pytest.mark.parametrize("preset", ["quick", "paper", "ci"])
def test_every_family_preset_resolves(task, preset):
    from metadagger.pipeline.run_config import resolve_config

    config = resolve_config(task, preset)
    assert config.task == task and config.pairs.seeds and config.benchmark is not None

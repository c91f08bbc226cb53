"""``--device``: where a run computes, chosen when it starts, in its stamps off the CPU, never mixed.

The tests marked ``gpu`` need a CUDA GPU and are skipped without one; ``scripts/gpu_check.sh``
runs them on a machine that has one (docs/performance.md, "On a GPU").
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
import yaml
from toy_task import CorridorTask
from typer.testing import CliRunner

from metadagger.cli.main import app
from metadagger.errors import UserError
from metadagger.imitation.bc import BCConfig, fit_bc
from metadagger.imitation.collect import collect
from metadagger.imitation.head_fits import HeadFit, fit_heads
from metadagger.imitation.lanes import EpisodeRequest, Lanes
from metadagger.pipeline.run_config import init_run, load_run
from metadagger.policies import make_policy
from metadagger.utils import device as device_module
from metadagger.utils.device import current_device, device_stamp, resolve_device, use_device
from metadagger.utils.executors import make_executor
from metadagger.utils.kernels import kernel_stamp

gpu = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU (scripts/gpu_check.sh)")


def _refused(*args: str) -> str:
    """The command's one error line (exit 2), run in this process."""
    result = CliRunner().invoke(app, [str(a) for a in args])
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert result.exit_code == 2 and len(lines) == 1 and lines[0].startswith("error: "), result.output
    return lines[0]


def test_a_device_value_resolves_or_is_one_line_naming_the_fix(monkeypatch):
    assert resolve_device("cpu") == "cpu"
    monkeypatch.setattr(device_module, "_cuda_available", lambda: False)
    assert resolve_device("auto") == "cpu"
    with pytest.raises(UserError, match="--device cuda, but torch sees no CUDA GPU.*pass --device cpu"):
        resolve_device("cuda")
    with pytest.raises(UserError, match="--device must be one of cpu, cuda, auto, got 'gpu'"):
        resolve_device("gpu")
    monkeypatch.setattr(device_module, "_cuda_available", lambda: True)
    assert resolve_device("auto") == "cuda" and resolve_device("cuda") == "cuda"


def test_on_the_cpu_nothing_is_stamped_so_cpu_artifacts_made_before_stay_current():
    assert current_device() == "cpu" and device_stamp() == {}
    assert "device" not in kernel_stamp() and "gpu" not in kernel_stamp()


def test_a_run_keeps_the_device_it_started_on(tmp_path, monkeypatch):
    run = tmp_path / "run"
    config = init_run(run, "carracing", "ci", device="auto")  # no GPU here: auto is the CPU
    assert config.device == "cpu"
    assert yaml.safe_load((run / "config.yaml").read_text())["device"] == "cpu"
    assert init_run(run, "carracing", "ci", device="cpu").device == "cpu"
    assert init_run(run, "carracing", "ci").device == "cpu"  # none named: the folder's
    monkeypatch.setattr(device_module, "_cuda_available", lambda: True)
    with pytest.raises(UserError, match="was made on cpu, not cuda: a run folder never mixes CPU and GPU artifacts"):
        init_run(run, "carracing", "ci", device="cuda")
    with pytest.raises(UserError, match="the device is chosen with --device, not --set"):
        load_run(run, ["device=cuda"])


def test_a_gpu_device_on_a_machine_without_one_is_one_error_line_before_any_work(tmp_path):
    if torch.cuda.is_available():
        pytest.skip("this machine has a GPU")
    new = tmp_path / "new"
    line = _refused("pistar", "--task", "carracing", "--preset", "ci", "--out", new, "--device", "cuda")
    assert "torch sees no CUDA GPU" in line and not new.exists()
    # a folder made on a GPU, resumed on a machine without one
    made = tmp_path / "made"
    init_run(made, "carracing", "ci")
    config = made / "config.yaml"
    config.write_text(config.read_text().replace("device: cpu", "device: cuda"))
    assert "torch sees no CUDA GPU" in _refused("pairs", "--out", made)
    assert not (made / "pairs").exists()


def test_ray_workers_are_refused_a_gpu_run(monkeypatch):
    monkeypatch.setattr(device_module, "_current", "cuda")
    with pytest.raises(UserError, match="executor 'ray' computes on CPUs, but this run's device is cuda"):
        make_executor("ray", workers=1)


def _worker_device(_: int) -> str:
    return current_device()


def test_pool_workers_compute_on_the_drivers_device():
    with make_executor("local", workers=2) as pool:
        assert sorted(pool.imap_unordered(_worker_device, range(4))) == ["cpu"] * 4


@pytest.fixture
def on_gpu():
    use_device("cuda")
    yield
    use_device("cpu")


def _lanes_episodes(task, policy, heads) -> list:
    with Lanes(task, policy.net, width=4) as lanes:
        return lanes.run([EpisodeRequest(seed, head) for seed, head in zip(range(6), heads)])


@gpu
def test_gpu_lanes_are_deterministic_and_act_as_on_the_cpu(on_gpu):
    task = CorridorTask()
    policy = make_policy(task, seed=3)
    heads = [make_policy(task, seed=10 + i).head_vector().numpy() for i in range(6)]
    first, again = _lanes_episodes(task, policy, heads), _lanes_episodes(task, policy, heads)
    for a, b in zip(first, again):
        np.testing.assert_array_equal(a.features, b.features)
        np.testing.assert_array_equal(a.learner_actions, b.learner_actions)
    use_device("cpu")
    on_cpu = _lanes_episodes(task, policy, heads)
    agree = np.mean([np.mean(a.learner_actions == b.learner_actions) for a, b in zip(first, on_cpu)])
    assert agree > 0.95
    for a, b in zip(first, on_cpu):
        np.testing.assert_allclose(a.features[: min(a.steps, b.steps)], b.features[: min(a.steps, b.steps)], atol=1e-3)


@gpu
def test_gpu_head_fits_and_whole_network_fits_are_deterministic_and_near_the_cpu(on_gpu):
    task = CorridorTask()
    policy = make_policy(task, seed=0)
    first, *others = [trajectory.to_dataset() for trajectory in collect(task, [0, 1, 2], policy=None)]
    data = first.concat(*others)
    features = policy.net.features(torch.from_numpy(data.obs)).detach()
    fits = [
        HeadFit(
            head=make_policy(task, seed=k).head_vector().detach(),
            features=features,
            targets=torch.from_numpy(data.labels),
            orders=torch.stack([torch.randperm(len(data), generator=torch.Generator().manual_seed(k))] * 3),
            lr=3e-3,
            weight_decay=0.0,
            batch_size=10,
            called=f"fit {k}",
        )
        for k in range(3)
    ]
    heads = [fitted.head for fitted in fit_heads(fits, out_dim=policy.net.head.out_features, discrete=True)]
    again = [fitted.head for fitted in fit_heads(fits, out_dim=policy.net.head.out_features, discrete=True)]
    assert all(torch.equal(a, b) for a, b in zip(heads, again)) and heads[0].device.type == "cpu"

    def whole() -> tuple[list[float], torch.Tensor]:
        fitted = make_policy(task, seed=0)
        losses = fit_bc(fitted, data, BCConfig(lr=1e-3, batch_size=16, epochs=2))["loss"]
        return losses, fitted.head_vector()

    (losses, head), (losses_again, head_again) = whole(), whole()
    assert losses == losses_again and torch.equal(head, head_again) and head.device.type == "cpu"
    use_device("cpu")
    cpu_heads = [fitted.head for fitted in fit_heads(fits, out_dim=policy.net.head.out_features, discrete=True)]
    for a, b in zip(heads, cpu_heads):
        torch.testing.assert_close(a, b, rtol=1e-3, atol=1e-4)
    cpu_losses, _ = whole()
    np.testing.assert_allclose(losses, cpu_losses, rtol=1e-3)

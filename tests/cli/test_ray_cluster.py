"""A real two-node Ray cluster on loopback: pairs, evaluation and benchmark rows made through
``--address`` equal the local process pool's byte for byte (slow: two Ray nodes and two ci runs)."""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
from pathlib import Path
from typing import Iterator

import pytest
from typer.testing import CliRunner

from metadagger.cli.main import app

pytest.importorskip("ray")
RAY = shutil.which("ray", path=str(Path(sys.executable).parent)) or shutil.which("ray")
COMPARED = ("pairs/summary.json", "eval/mdm.csv", "eval/oneshot.csv", "benchmark/queries.csv", "benchmark/summary.json")


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _without_ray_variables(environ: dict[str, str]) -> dict[str, str]:
    return {name: value for name, value in environ.items() if not name.startswith("RAY_")}


@pytest.fixture(scope="module")
def cluster(tmp_path_factory) -> Iterator[tuple[str, Path]]:
    """``ray start --head`` and one ``ray start --address`` worker node, one CPU each, loopback
    only; a fresh HOME and none of the RAY_ variables so no token or state of another Ray instance
    on this machine is used (a ``ray.init`` earlier in this process sets RAY_AUTH_MODE=token)."""
    if RAY is None:
        pytest.skip("the ray command is not installed")
    home = tmp_path_factory.mktemp("ray-home")
    env = {**_without_ray_variables(os.environ), "HOME": str(home), "RAY_USAGE_STATS_ENABLED": "0"}
    address = f"127.0.0.1:{_free_port()}"
    common = ["--node-ip-address", "127.0.0.1", "--num-cpus", "1", "--disable-usage-stats"]
    try:
        subprocess.run(
            [
                RAY,
                "start",
                "--head",
                "--port",
                address.split(":")[1],
                "--include-dashboard",
                "false",
                "--temp-dir",
                str(home / "ray"),
                *common,
            ],
            env=env,
            check=True,
            capture_output=True,
            timeout=180,
        )
        subprocess.run(
            [RAY, "start", "--address", address, *common], env=env, check=True, capture_output=True, timeout=180
        )
        yield address, home
    finally:
        subprocess.run([RAY, "stop", "--force"], env=env, capture_output=True, timeout=120)


@pytest.mark.slow
def test_rows_made_on_a_two_node_cluster_equal_the_local_ones(cluster, tmp_path):
    address, home = cluster
    runner = CliRunner()
    local, remote = tmp_path / "local", tmp_path / "remote"
    result = runner.invoke(
        app, ["reproduce", "--task", "carracing", "--preset", "ci", "--out", str(local), "--workers", "2"]
    )
    assert result.exit_code == 0, result.output
    shutil.copytree(local, remote)
    for made_by_workers in ("pairs", "eval", "benchmark", "report"):
        shutil.rmtree(remote / made_by_workers)
    # the driver in a process of its own: no Ray state of this process (an earlier test's local
    # ray.init) and none of this machine's (a fresh HOME)
    env = {**_without_ray_variables(os.environ), "HOME": str(home)}
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "metadagger.cli",
            "reproduce",
            "--task",
            "carracing",
            "--preset",
            "ci",
            "--out",
            str(remote),
            "--executor",
            "ray",
            "--address",
            address,
        ],
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    for name in COMPARED:
        assert (remote / name).read_bytes() == (local / name).read_bytes(), name
    for pair in sorted((local / "pairs").glob("*.safetensors")):
        assert (remote / "pairs" / pair.name).read_bytes() == pair.read_bytes(), pair.name

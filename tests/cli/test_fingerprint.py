"""``metadagger bench ops``: kernel fingerprints that name where two machines part."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from metadagger.cli.fingerprint import compare_fingerprints, fingerprint_kernels, read_fingerprint
from metadagger.errors import UserError

REPO = Path(__file__).resolve().parents[2]
MACHINES = sorted((REPO / "results" / "machines").glob("*.json"))


@pytest.fixture(scope="module")
def here() -> dict:
    return fingerprint_kernels()


def _names(fingerprint: dict) -> list[str]:
    return [entry["op"] for entry in fingerprint["ops"]]


def _set(fingerprint: dict, name: str, sha256: str) -> None:
    next(entry for entry in fingerprint["ops"] if entry["op"] == name)["sha256"] = sha256


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "metadagger.cli", "bench", "ops", *args],
        capture_output=True,
        text=True,
        env={**os.environ, "MUJOCO_GL": "egl"},
    )


def test_a_fingerprint_covers_a_run_in_order_and_repeats_bit_for_bit(here):
    names = _names(here)
    assert names[0].startswith("numpy.") and names[-1].startswith("carracing frames")
    assert (
        names.index("torch.conv2d (oneDNN)")
        < names.index("policy step: logits")
        < names.index("policy step: weights after Adam")
    )
    # every parameter's gradient is its own entry, so a difference names the layer
    assert sum(name.startswith("policy step: grad ") for name in names) == 14
    assert all(len(entry["sha256"]) == 64 for entry in here["ops"])
    again = fingerprint_kernels()
    assert again["ops"] == here["ops"]
    assert here["machine"]["cpu"] and here["kernels"]


def test_compare_names_the_first_computation_that_differs(here):
    assert compare_fingerprints(here, here)["differ"] == []
    other = json.loads(json.dumps(here))
    for name in ("policy step: loss", "torch.conv2d weight gradient"):
        _set(other, name, "0" * 64)
    other["ops"] = [entry for entry in other["ops"] if entry["op"] != "numpy.exp (SIMD loops)"]
    compared = compare_fingerprints(here, other)
    assert compared["differ"] == ["torch.conv2d weight gradient", "policy step: loss"]
    assert compared["first_difference"] == "torch.conv2d weight gradient"
    assert compared["only_here"] == ["numpy.exp (SIMD loops)"] and compared["only_there"] == []


def test_the_command_writes_a_fingerprint_and_compares_with_another(tmp_path):
    first = tmp_path / "a.json"
    done = _cli("--out", str(first))
    assert done.returncode == 0, done.stderr
    written = read_fingerprint(first)
    assert written["commit"] and written["kernels"]
    tampered = json.loads(first.read_text())
    _set(tampered, "torch.linear (MKL sgemm)", "f" * 64)
    (tmp_path / "b.json").write_text(json.dumps(tampered))
    done = _cli("--out", str(tmp_path / "c.json"), "--compare", str(tmp_path / "b.json"))
    assert done.returncode == 0, done.stderr
    compared = json.loads((tmp_path / "c.json").read_text())["compared"]
    assert compared["differ"] == ["torch.linear (MKL sgemm)"]
    assert '"first_difference": "torch.linear (MKL sgemm)"' in done.stdout


@pytest.mark.parametrize("content", [None, "{}", "not json", '{"ops": [{"op": "x"}]}'])
def test_a_bad_compare_file_is_one_error_line_before_any_work(tmp_path, content):
    from typer.testing import CliRunner

    from metadagger.cli.main import app

    other = tmp_path / "other.json"
    if content is not None:
        other.write_text(content)
    # in this process: the file is read before any work, so nothing is fingerprinted
    done = CliRunner().invoke(app, ["bench", "ops", "--out", str(tmp_path / "out.json"), "--compare", str(other)])
    lines = [line for line in done.output.splitlines() if line.strip()]
    assert done.exit_code == 2 and len(lines) == 1, done.output
    assert str(other) in lines[0] and "metadagger bench ops" in lines[0]
    assert not (tmp_path / "out.json").exists()
    with pytest.raises(UserError):
        read_fingerprint(other)


@pytest.mark.parametrize("recorded", MACHINES, ids=[p.stem for p in MACHINES])
def test_the_registry_machines_fingerprints_are_current(here, recorded):
    """A registry machine's fingerprint names computations this code makes, in its order (a file
    recorded before an op was added lacks that op: it is compared on the ops it has); on any
    machine with the same pins, whatever its CPU, every one of them gives the same bits
    (docs/architecture.md, "What is shown"). A file made at another NUMERICS is still held to
    the ops it shares with this code; only where one of them differs is it skipped, since the new
    numerics may have changed that op's computation."""
    theirs = read_fingerprint(recorded)
    ours = _names(here)
    assert _names(theirs) == [name for name in ours if name in _names(theirs)], (
        f"regenerate with `metadagger bench ops --out {recorded.relative_to(REPO)}`"
    )
    if theirs["machine"]["kernels"] != here["machine"]["kernels"]:
        pytest.skip(f"{recorded.name} was made with other kernel pins")
    differ = compare_fingerprints(here, theirs)["differ"]
    if differ and theirs["machine"]["numerics"] != here["machine"]["numerics"]:
        # an op whose computation a new NUMERICS changed differs on every machine: not the CPU's doing
        pytest.skip(
            f"{recorded.name} was made at NUMERICS {theirs['machine']['numerics']} and differs in {differ[0]}: "
            "regenerate it on that machine"
        )
    assert differ == []


def test_the_lanes_kernels_are_fingerprinted_after_the_policy_step(here):
    names = _names(here)
    forward, fits = names.index("lanes: trunk forward (32 rows, 5 padded)"), names.index("lanes: batched head fits")
    assert names.index("policy step: weights after Adam") < forward < fits < len(names) - 1

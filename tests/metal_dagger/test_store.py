"""The pair store: round trip, kill safety (torn lines, .tmp files, SIGKILL + resume), splits."""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import torch

from metadagger.errors import CheckpointError, UserError
from metadagger.metal_dagger.store import PairSplit, PairStore
from metadagger.utils.io import save_tensors

DIM = 6


def _pair(seed: int, dim: int = DIM) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return torch.randn(dim, generator=g), torch.randn(dim, generator=g)


def _record(seed: int, *, kept: bool = True) -> dict:
    outcome = {"success": kept, "reward": 1.5 * seed, "steps": 100 + seed, "expert_queries": 10 * seed}
    return {"bc": {**outcome, "success": not kept}, "da": outcome, "kept": kept, "dagger_rounds": 3}


def _fill(store: PairStore, seeds: range | list[int], *, kept=lambda s: True) -> None:
    for seed in seeds:
        store.write(seed, *_pair(seed), _record(seed, kept=kept(seed)))


def test_round_trip(tmp_path: Path) -> None:
    store = PairStore(tmp_path / "pairs")
    _fill(store, [5, 2, 9])
    assert store.done_seeds() == {2, 5, 9}
    records = store.records()
    assert [r["seed"] for r in records] == [2, 5, 9]
    assert records[0] == {**_record(2), "seed": 2}
    w_bc, w_da = store.load([9, 2])
    assert w_bc.shape == w_da.shape == (2, DIM) and w_bc.dtype == torch.float32
    assert torch.equal(w_bc[0], _pair(9)[0]) and torch.equal(w_da[1], _pair(2)[1])


def test_last_record_per_seed_wins(tmp_path: Path) -> None:
    store = PairStore(tmp_path)
    _fill(store, [1, 2])
    store.write(1, *_pair(100), _record(1, kept=False))
    assert [r["kept"] for r in store.records()] == [False, True]
    assert torch.equal(store.load([1])[0][0], _pair(100)[0])


def test_torn_last_line_is_ignored_then_repaired(tmp_path: Path) -> None:
    store = PairStore(tmp_path)
    _fill(store, [0, 1])
    with open(store.jsonl_path, "ab") as f:
        f.write(b'{"bc":{"success":false,"rew')  # what a SIGKILL inside write() leaves
    assert store.done_seeds() == {0, 1}
    assert [r["seed"] for r in store.records()] == [0, 1]
    _fill(store, [2])
    lines = store.jsonl_path.read_bytes().split(b"\n")
    assert lines[-1] == b"" and [json.loads(line)["seed"] for line in lines[:-1]] == [0, 1, 2]


def test_leftover_tmp_and_unrecorded_or_missing_files_are_not_done(tmp_path: Path) -> None:
    store = PairStore(tmp_path)
    _fill(store, [0, 1])
    stale = tmp_path / ".3.safetensors.x1y2.tmp"  # killed inside the atomic write of seed 3
    stale.write_bytes(b"half a file")
    save_tensors(store.pair_path(4), dict(zip(("w_bc", "w_da"), _pair(4))))  # killed before its JSON line
    store.pair_path(1).unlink()  # record without its file
    assert store.done_seeds() == {0}
    _fill(store, [3])
    assert not stale.exists()
    assert store.done_seeds() == {0, 3}


def test_identical_inputs_give_byte_identical_files(tmp_path: Path) -> None:
    stores = [PairStore(tmp_path / name) for name in ("a", "b")]
    for store in stores:
        _fill(store, [3, 1, 2])
    files_a, files_b = (sorted(p.name for p in s.root.iterdir()) for s in stores)
    assert files_a == files_b == ["1.safetensors", "2.safetensors", "3.safetensors", "pairs.jsonl"]
    for name in files_a:
        assert (stores[0].root / name).read_bytes() == (stores[1].root / name).read_bytes()


_WRITER = textwrap.dedent(
    """
    import sys, time
    import torch
    from metadagger.metal_dagger.store import PairStore

    store = PairStore(sys.argv[1])
    done = store.done_seeds()
    for seed in range(int(sys.argv[2])):
        if seed in done:
            continue
        time.sleep(0.02)  # stands in for BC + DAgger on this seed
        g = torch.Generator().manual_seed(seed)
        outcome = {"success": True, "reward": 1.0, "steps": 10, "expert_queries": 5}
        store.write(seed, torch.randn(6, generator=g), torch.randn(6, generator=g),
                    {"bc": outcome, "da": outcome, "kept": True})
        print(seed, flush=True)
    """
)


def test_sigkill_mid_run_then_resume_completes_without_redoing(tmp_path: Path) -> None:
    script, root, n = tmp_path / "writer.py", tmp_path / "pairs", 40
    script.write_text(_WRITER)
    proc = subprocess.Popen([sys.executable, str(script), str(root), str(n)], stdout=subprocess.PIPE, text=True)
    try:
        for _ in range(5):
            assert proc.stdout.readline(), "writer ended before it could be killed"
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        proc.kill()
    store = PairStore(root)
    first = store.done_seeds()
    assert 5 <= len(first) < n
    before = {s: store.pair_path(s).read_bytes() for s in first}

    resumed = subprocess.run(
        [sys.executable, str(script), str(root), str(n)], capture_output=True, text=True, check=True
    )
    second = {int(line) for line in resumed.stdout.split()}
    assert second == set(range(n)) - first  # nothing redone, nothing left out
    assert store.done_seeds() == set(range(n))
    assert {s: store.pair_path(s).read_bytes() for s in first} == before
    seeds_per_line = [json.loads(line)["seed"] for line in store.jsonl_path.read_text().splitlines()]
    assert sorted(seeds_per_line) == list(range(n))  # one line per seed


def test_split_is_seeded_and_uses_kept_pairs(tmp_path: Path) -> None:
    store = PairStore(tmp_path)
    _fill(store, range(20), kept=lambda s: s % 4 != 0)  # 15 kept
    split = store.load_split(val_fraction=0.2, seed=0)
    assert len(split.train_seeds) == 12 and len(split.val_seeds) == 3
    assert set(split.train_seeds) | set(split.val_seeds) == {s for s in range(20) if s % 4}
    assert _same_split(split, store.load_split(val_fraction=0.2, seed=0))
    assert split.val_seeds != store.load_split(val_fraction=0.2, seed=1).val_seeds
    w_bc, w_da = store.load(split.val_seeds)
    assert torch.equal(split.w_bc_val, w_bc) and torch.equal(split.w_da_val, w_da)
    everything = store.load_split(val_fraction=0.0, seed=0, kept_only=False)
    assert everything.train_seeds == tuple(range(20)) and everything.w_bc_val.shape == (0, DIM)


def _same_split(a: PairSplit, b: PairSplit) -> bool:
    return a.train_seeds == b.train_seeds and a.val_seeds == b.val_seeds and torch.equal(a.w_bc_train, b.w_bc_train)


def test_a_small_positive_val_fraction_keeps_one_val_pair(tmp_path: Path) -> None:
    store = PairStore(tmp_path)
    _fill(store, range(3))
    assert len(store.load_split(val_fraction=0.01, seed=0).val_seeds) == 1


@pytest.mark.parametrize(
    ("val_fraction", "match"), [(1.0, r"val_fraction must be in \[0, 1\), got 1.0"), (0.9, "too few")]
)
def test_split_errors(tmp_path: Path, val_fraction: float, match: str) -> None:
    store = PairStore(tmp_path)
    _fill(store, range(2))
    with pytest.raises(UserError, match=match):
        store.load_split(val_fraction=val_fraction, seed=0)


def test_missing_store_is_a_user_error_but_has_no_done_seeds(tmp_path: Path) -> None:
    store = PairStore(tmp_path / "nope")
    assert store.done_seeds() == set()
    with pytest.raises(UserError, match="pair store not found: .*nope"):
        store.records()


def test_bad_pair_files_are_checkpoint_errors(tmp_path: Path) -> None:
    store = PairStore(tmp_path)
    _fill(store, [0, 1, 2])
    save_tensors(store.pair_path(1), {"w_bc": torch.zeros(DIM), "w_da": torch.zeros(DIM + 1)})
    store.pair_path(2).write_bytes(b"not safetensors")
    with pytest.raises(CheckpointError, match=r"pair file .*1\.safetensors is not a valid pair .*same length"):
        store.load([1])
    with pytest.raises(CheckpointError, match=r"2\.safetensors is corrupt"):
        store.load([2])
    with pytest.raises(CheckpointError, match="seed 7 has no record"):
        store.load([7])
    store.write(3, *_pair(3, dim=DIM + 2), _record(3))
    with pytest.raises(CheckpointError, match=r"3\.safetensors holds vectors of length 8, but seed 0 has length 6"):
        store.load([0, 3])
    assert store.done_seeds() == {0, 3}


@pytest.mark.parametrize(
    ("damage", "problem"),
    [
        (lambda path: path.write_bytes(path.read_bytes()[:100]), r"is corrupt or not a safetensors file \(.+\)"),
        (lambda path: path.write_bytes(b"x\n"), r"is corrupt or not a safetensors file \(.+\)"),
        (lambda path: path.write_bytes(b""), r"is corrupt or not a safetensors file \(.+\)"),
        (
            lambda path: save_tensors(path, {"a": torch.zeros(DIM), "w_da": torch.zeros(DIM)}),
            r"is not a valid pair \(it holds tensors \['a', 'w_da'\], expected w_bc, w_da and optionally context\)",
        ),
        (
            lambda path: save_tensors(path, {"w_bc": torch.zeros(DIM), "w_da": torch.zeros(DIM, dtype=torch.float64)}),
            r"is not a valid pair \(w_da must be a non-empty 1-D float32 tensor, got torch.float64",
        ),
        (lambda path: path.unlink(), "is missing"),
    ],
    ids=["truncated", "garbage", "empty", "other-tensors", "other-dtype", "deleted"],
)
def test_a_recorded_seed_whose_file_does_not_load_is_named_with_the_fix(tmp_path: Path, damage, problem: str) -> None:
    store = PairStore(tmp_path)
    _fill(store, [0, 1, 2])
    damage(store.pair_path(1))
    assert store.done_seeds() == {0, 2}  # redone by the next collection
    store.check_readable([7, 0, 2])  # unrecorded seeds and readable files pass
    fix = "run `metadagger pairs --out RUN`, which collects that pair again"
    with pytest.raises(CheckpointError) as info:
        store.check_readable([0, 1, 2], fix=fix)
    message = str(info.value)
    assert re.fullmatch(f"pair file {re.escape(str(store.pair_path(1)))} {problem}.*; {re.escape(fix)}", message)
    assert "\n" not in message


def test_a_garbled_complete_line_is_a_checkpoint_error(tmp_path: Path) -> None:
    store = PairStore(tmp_path)
    _fill(store, [0])
    with open(store.jsonl_path, "ab") as f:
        f.write(b"garbage\n")
    with pytest.raises(CheckpointError, match="line 2 is not a pair record"):
        store.records()


@pytest.mark.parametrize(
    ("args", "match"),
    [
        ((-1, *_pair(0), _record(0)), "seed must be a non-negative int, got -1"),
        (
            (0, torch.zeros(DIM, dtype=torch.float64), torch.zeros(DIM), _record(0)),
            "w_bc must be a non-empty 1-D float32",
        ),
        (
            (0, torch.zeros(2, 3), torch.zeros(2, 3), _record(0)),
            r"1-D float32 tensor, got torch.float32 of shape \(2, 3\)",
        ),
        ((0, torch.zeros(3), torch.zeros(4), _record(0)), "same length, got 3 and 4"),
        ((0, *_pair(0), {**_record(0), "seed": 1}), "record seed 1 does not match the seed written, 0"),
        ((0, *_pair(0), {**_record(0), "kept": "yes"}), "'kept' must be a bool"),
        (
            (0, *_pair(0), {**_record(0), "da": {"success": True}}),
            r"record 'da' must be a mapping .* missing \['reward'",
        ),
        ((0, *_pair(0), {**_record(0), "extra": object()}), "not JSON-serialisable"),
    ],
)
def test_write_rejects_bad_input_and_writes_nothing(tmp_path: Path, args: tuple, match: str) -> None:
    store = PairStore(tmp_path / "pairs")
    with pytest.raises(ValueError, match=match):
        store.write(*args)
    assert not store.root.exists()


def test_contexts_travel_with_the_pairs_into_the_split(tmp_path: Path) -> None:
    store = PairStore(tmp_path / "pairs")
    for seed in range(5):
        store.write(seed, *_pair(seed), _record(seed), context=torch.full((3,), float(seed)))
    assert torch.equal(store.load_contexts([4, 1]), torch.tensor([[4.0] * 3, [1.0] * 3]))
    split = store.load_split(val_fraction=0.4, seed=0)
    for rows, seeds in ((split.context_train, split.train_seeds), (split.context_val, split.val_seeds)):
        assert torch.equal(rows[:, 0], torch.tensor(seeds, dtype=torch.float32))
    fewer = split.with_train_rows(torch.tensor([1]))
    assert fewer.train_seeds == (split.train_seeds[1],) and torch.equal(fewer.context_train, split.context_train[1:2])
    store.write(5, *_pair(5), _record(5))  # a pair stored without a context: the split has none
    assert store.load_split(val_fraction=0.4, seed=0).context_train is None
    with pytest.raises(ValueError, match="context must be a 1-D float32 tensor"):
        store.write(6, *_pair(6), _record(6), context=torch.zeros(2, 2))
    with pytest.raises(ValueError, match=r"context_val has shape \(2, 4\), expected \(2, 3\)"):
        PairSplit(
            w_bc_train=split.w_bc_train,
            w_da_train=split.w_da_train,
            w_bc_val=split.w_bc_val,
            w_da_val=split.w_da_val,
            train_seeds=split.train_seeds,
            val_seeds=split.val_seeds,
            context_train=split.context_train,
            context_val=torch.zeros(2, 4),
        )


def test_a_damaged_record_or_a_nan_pair_is_one_line_naming_the_file(tmp_path):
    store = PairStore(tmp_path)
    store.write(1000, *_pair(1000), _record(1000))
    with open(store.jsonl_path, "a") as f:
        f.write('{"seed":1003,"stamp":"x","kept":true}\n')
    with pytest.raises(
        CheckpointError, match=r"pairs.jsonl has a damaged pair record .*delete that line and re-run metadagger pairs"
    ):
        store.records()
    store = PairStore(tmp_path / "nan")
    w_bc, w_da = _pair(1000)
    with pytest.raises(UserError, match="holds NaN or infinite values"):
        store.write(1000, w_bc, torch.full_like(w_da, float("nan")), _record(1000))
    assert not list((tmp_path / "nan").glob("*.safetensors"))

"""Standardiser, controls, input checks and checkpoint errors of :class:`Mapper`."""

from __future__ import annotations

import numpy as np
import pytest
import torch

import metadagger
from metadagger.errors import CheckpointError, UserError
from metadagger.mapping.mappers import Mapper, Standardizer, build_networks, load_mapper
from metadagger.utils.io import load_tensors, read_metadata, save_tensors


def test_standardizer_fit_transform_inverse(rng):
    x = torch.tensor(rng.normal(loc=3.0, scale=2.0, size=(50, 4)), dtype=torch.float32)
    s = Standardizer.fit(x)
    z = s.transform(x)
    torch.testing.assert_close(z.mean(0), torch.zeros(4), atol=1e-5, rtol=0)
    torch.testing.assert_close(z.std(0, unbiased=False), torch.ones(4), atol=1e-5, rtol=0)
    torch.testing.assert_close(s.inverse(z), x, atol=1e-5, rtol=0)


def test_standardizer_floors_near_constant_entries():
    x = torch.stack([torch.linspace(-1, 1, 10), torch.full((10,), 0.5)], dim=1)
    s = Standardizer.fit(x)
    assert float(s.std[1]) == pytest.approx(Standardizer.REL_FLOOR * float(x.std(0, unbiased=False).mean()))
    assert torch.isfinite(s.transform(torch.tensor([[0.0, 0.6]]))).all()
    assert torch.equal(Standardizer.fit(torch.ones(5, 3)).std, torch.ones(3))  # nothing varies: unit scale


def test_controls_return_their_constant(tmp_path):
    head = np.arange(6, dtype=np.float32)
    pistar = Mapper.pistar_head(head)
    assert pistar.kind == "pistar-head" and pistar.in_dim == 6
    np.testing.assert_array_equal(pistar(np.zeros(6, dtype=np.float32)), head)
    rows = torch.tensor([[0.0, 2.0], [2.0, 4.0]])
    mean = Mapper.mean_da(rows)
    np.testing.assert_array_equal(mean.map_batch(np.ones((3, 2), dtype=np.float32)), np.tile([1.0, 3.0], (3, 1)))
    out = pistar(torch.zeros(6))
    assert isinstance(out, np.ndarray) and out.dtype == np.float32 and out.shape == (6,)
    pistar.save(tmp_path / "p.safetensors")
    np.testing.assert_array_equal(metadagger.load_mapper(tmp_path / "p.safetensors")(head), head)


def test_wrong_input_is_a_user_error():
    m = Mapper.pistar_head(np.zeros(12, dtype=np.float32))
    with pytest.raises(UserError, match="got 7, expected 12: the head of the policy"):
        m(np.zeros(7, dtype=np.float32))
    with pytest.raises(UserError, match="1-D head vector"):
        m(np.zeros((2, 12), dtype=np.float32))
    with pytest.raises(UserError, match="2-D batch"):
        m.map_batch(np.zeros(12, dtype=np.float32))
    with pytest.raises(UserError, match="float"):
        m(np.array(["a"] * 12))
    with pytest.raises(UserError, match="1-D head vector"):
        Mapper.pistar_head(np.zeros((2, 3)))


def test_missing_corrupt_or_foreign_file_is_a_checkpoint_error(tmp_path):
    with pytest.raises(CheckpointError, match="not found"):
        load_mapper(tmp_path / "absent.safetensors")
    corrupt = tmp_path / "corrupt.safetensors"
    corrupt.write_bytes(b"\x10\x00\x00\x00\x00\x00\x00\x00not a header")
    with pytest.raises(CheckpointError, match="corrupt"):
        load_mapper(corrupt)
    foreign = tmp_path / "policy.safetensors"
    save_tensors(foreign, {"w": torch.zeros(3)}, metadata={"task": "carracing"})
    with pytest.raises(CheckpointError, match="not a mapper file"):
        metadagger.load_mapper(foreign)


def test_truncated_mapper_file_is_a_checkpoint_error(tmp_path):
    path = Mapper.pistar_head(np.zeros(4, dtype=np.float32)).save(tmp_path / "m.safetensors")
    path.write_bytes(path.read_bytes()[:-8])
    with pytest.raises(CheckpointError, match="corrupt"):
        load_mapper(path)


def test_tensors_that_do_not_fit_the_recorded_networks_are_named_in_one_line(tmp_path):
    arch = {"hidden": [8], "latent": 2, "ae_hidden": [8], "batchnorm": False, "dropout": 0.0, "ae_dropout": 0.0}
    scalers = {name: Standardizer(mean=torch.zeros(4), std=torch.ones(4)) for name in ("bc", "da")}
    mapper = Mapper(
        kind="dm", dim=4, networks=build_networks("dm", 4, **arch), scalers=scalers, config={"kind": "dm", **arch}
    )
    path = mapper.save(tmp_path / "m.safetensors")
    tensors = load_tensors(path)
    shape = tuple(tensors["networks.dm.0.0.weight"].shape)
    tensors["networks.dm.0.0.weight"] = torch.zeros(3, 3)
    del tensors["networks.dm.1.bias"]
    save_tensors(path, tensors, metadata=read_metadata(path))
    with pytest.raises(CheckpointError) as info:
        load_mapper(path)
    message = str(info.value)
    assert "\n" not in message
    assert message == (
        f"mapper file {path} does not match its own metadata (missing tensor(s) networks.dm.1.bias; "
        f"networks.dm.0.0.weight has shape (3, 3), expected {shape}); delete it and re-run train-mapper"
    )


def test_a_mapper_file_replaced_after_its_fingerprint_is_refused(tmp_path):
    """A worker loads the bytes the stage's stamps fingerprinted, or refuses: a mapper swapped
    while a stage runs never yields rows labelled with the old one."""
    from metadagger.mapping.mappers import MapperFile, cached_mapper
    from metadagger.runfolder.stamps import file_fingerprint

    path = Mapper.pistar_head(np.zeros(4, dtype=np.float32)).save(tmp_path / "m.safetensors")
    recorded = MapperFile(str(path), file_fingerprint(path))
    assert cached_mapper(recorded).dim == 4
    Mapper.pistar_head(np.ones(4, dtype=np.float32)).save(tmp_path / "other.safetensors").replace(path)
    cached_mapper.cache_clear()  # a fresh worker
    with pytest.raises(UserError, match="changed while this stage ran"):
        cached_mapper(recorded)

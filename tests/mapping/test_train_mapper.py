"""Training every kind: learning, standardisation, save/load, determinism, resume and curves."""

from __future__ import annotations

import csv
import dataclasses

import numpy as np
import pytest
import torch
from mapping_data import synthetic_split, tiny_config

from metadagger.errors import DivergedError, UserError
from metadagger.evaluation.curves import plot_curves
from metadagger.mapping import train as train_module
from metadagger.mapping.config import MapperConfig, paper_config
from metadagger.mapping.mappers import Mapper, load_mapper
from metadagger.mapping.registry import kind_names
from metadagger.mapping.train import CURVE_COLUMNS, MapperJob, evaluate_mapping, train_mapper, train_mappers
from metadagger.runfolder.driver import StageOptions
from metadagger.utils.kernels import mkl_vector_math_calls

KINDS = kind_names()
STAGES = {
    "dm": ["dm"],
    "sam": ["sigma_all", "h"],
    "tam": ["sigma_bc", "sigma_da", "h"],
    "ridge": ["ridge"],
    "modes": ["modes"],
    "conditioned": ["ridge"],
    "mean-da": ["mean-da"],
    "pistar-head": ["pistar-head"],
}


@pytest.fixture(scope="module")
def trained(tmp_path_factory, split, pistar_head):
    """One mapper of every kind, trained once for the whole module: kind -> (mapper, out_dir)."""
    out = {}
    for kind in KINDS:
        out_dir = tmp_path_factory.mktemp(kind)
        out[kind] = (train_mapper(split, tiny_config(kind), out_dir, pistar_head=pistar_head, progress=False), out_dir)
    return out


def _curves(out_dir):
    with open(out_dir / "curves.csv", newline="") as f:
        return list(csv.DictReader(f))


@pytest.mark.parametrize("kind", ["dm", "sam", "tam", "ridge"])
def test_learned_kinds_beat_mean_da_on_held_out_pairs(trained, split, kind):
    mean_da = split.w_da_train.mean(0)
    scores = evaluate_mapping(trained[kind][0], split.w_bc_val, split.w_da_val, mean_da=mean_da)
    control = evaluate_mapping(trained["mean-da"][0], split.w_bc_val, split.w_da_val, mean_da=mean_da)
    assert control["relative_mse"] == pytest.approx(1.0)
    assert scores["relative_mse"] < 0.5, scores
    assert scores["cosine"] > control["cosine"]


@pytest.mark.parametrize("kind", KINDS)
def test_save_load_round_trip_is_exact(trained, split, kind):
    mapper, out_dir = trained[kind]
    loaded = load_mapper(out_dir / "mapper.safetensors")
    assert (loaded.kind, loaded.in_dim, loaded.config) == (kind, split.w_bc_val.shape[1], mapper.config)
    np.testing.assert_array_equal(
        loaded.map_batch(split.w_bc_val, split.context_val), mapper.map_batch(split.w_bc_val, split.context_val)
    )
    w, c = split.w_bc_val[0].numpy(), split.context_val[0].numpy()
    np.testing.assert_array_equal(loaded(w, c), mapper(w, c))
    assert mapper(w, c).dtype == np.float32 and mapper(w, c).shape == w.shape
    assert loaded.needs_context == (kind == "conditioned") and loaded.context_dim == (
        c.shape[0] if kind == "conditioned" else 0
    )


@pytest.mark.parametrize("kind", KINDS)
def test_curves_csv_and_png(trained, kind):
    out_dir = trained[kind][1]
    rows = _curves(out_dir)
    assert tuple(rows[0]) == CURVE_COLUMNS
    assert list(dict.fromkeys(r["model"] for r in rows)) == STAGES[kind]
    final = [r for r in rows if r["model"] == STAGES[kind][-1]]
    assert all(r["val_mse_weights"] and r["train_mse_weights"] for r in final)  # comparable across kinds
    assert not any(r["val_mse_weights"] for r in rows if r not in final)
    if kind in ("dm", "sam", "tam"):
        assert [int(r["epoch"]) for r in final] == list(range(1, 41))
        assert float(final[-1]["train_loss"]) < float(final[0]["train_loss"])
    png = plot_curves(out_dir / "curves.csv", out_dir / "curves.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_eval_mode_makes_calls_repeatable(trained, split):
    mapper = trained["sam"][0]
    for net in mapper.networks.values():
        net.train()  # a caller leaving training mode on must not make Dropout act at inference
    w = split.w_bc_val[0]
    np.testing.assert_array_equal(mapper(w), mapper(w))


def test_standardisers_are_fitted_on_the_training_split_only(tmp_path):
    clean = synthetic_split()
    # Validation rows far off: any leak into the standardisers would move their mean.
    split = dataclasses.replace(clean, w_bc_val=clean.w_bc_val + 100.0, w_da_val=clean.w_da_val - 100.0)
    dm = train_mapper(split, tiny_config("dm", epochs=1), tmp_path / "dm", progress=False)
    torch.testing.assert_close(dm.scalers["bc"].mean, clean.w_bc_train.mean(0))
    torch.testing.assert_close(dm.scalers["da"].std, clean.w_da_train.std(0, unbiased=False).clamp_min(1e-9))
    sam = train_mapper(split, tiny_config("sam", epochs=1, ae_epochs=1), tmp_path / "sam", progress=False)
    both = torch.cat([clean.w_bc_train, clean.w_da_train])
    torch.testing.assert_close(sam.scalers["all"].mean, both.mean(0))
    mean_da = train_mapper(split, tiny_config("mean-da"), tmp_path / "mean", progress=False)
    np.testing.assert_allclose(mean_da(clean.w_bc_val[0]), clean.w_da_train.mean(0).numpy(), rtol=1e-6)


def test_training_twice_gives_identical_files(tmp_path, split):
    config = tiny_config("tam", epochs=5, ae_epochs=5)  # dropout 0.1: Dropout's draws must be seeded too
    torch.manual_seed(123)
    train_mapper(split, config, tmp_path / "a", progress=False)
    torch.manual_seed(456)  # the global generator must not matter
    train_mapper(split, config, tmp_path / "b", progress=False)
    for name in ("mapper.safetensors", "curves.csv"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()
    other = train_mapper(split, dataclasses.replace(config, seed=1), tmp_path / "c", progress=False)
    assert not np.array_equal(
        other.map_batch(split.w_bc_val), load_mapper(tmp_path / "a" / "mapper.safetensors").map_batch(split.w_bc_val)
    )


def test_parallel_fits_equal_the_drivers_and_resume(tmp_path, split, pistar_head, monkeypatch):
    kinds = ("tam", "dm", "ridge", "pistar-head")
    configs = {kind: tiny_config(kind, epochs=5, ae_epochs=5) for kind in kinds}
    for kind in kinds:
        train_mapper(split, configs[kind], tmp_path / "driver" / kind, pistar_head=pistar_head, progress=False)
    jobs = [
        MapperJob(split=split, config=configs[kind], out_dir=tmp_path / "pool" / kind, pistar_head=pistar_head)
        for kind in kinds
    ]
    mappers = train_mappers(jobs, options=StageOptions(workers=2, progress=False))
    assert [m.kind for m in mappers] == list(kinds)  # in the jobs' order, whatever finished first
    for kind in kinds:
        for name in ("mapper.safetensors", "curves.csv"):
            assert (tmp_path / "pool" / kind / name).read_bytes() == (tmp_path / "driver" / kind / name).read_bytes(), (
                kind,
                name,
            )

    # finished mappers are loaded, not refitted; a stale one is refused before any fit starts
    def no_fit(*args, **kwargs):
        raise AssertionError("a fit ran")

    monkeypatch.setattr(train_module, "fit_mapper", no_fit)
    again = train_mappers(jobs, options=StageOptions(workers=2, progress=False))
    np.testing.assert_array_equal(again[0].map_batch(split.w_bc_val), mappers[0].map_batch(split.w_bc_val))
    (tmp_path / "pool" / "dm" / "mapper.safetensors").unlink()  # dm is due, tam is stale
    stale = dataclasses.replace(jobs[0], config=tiny_config("tam", epochs=6, ae_epochs=5))
    with pytest.raises(UserError, match="made from other inputs"):
        train_mappers([jobs[1], stale], options=StageOptions(workers=2, progress=False))
    assert not (tmp_path / "pool" / "dm" / "mapper.safetensors").exists()  # the due one was not fitted either


def test_a_user_error_in_a_worker_is_one_short_line(tmp_path, split):
    one_pair = split.with_train_rows(torch.tensor([0]))
    jobs = [
        MapperJob(split=split, config=tiny_config("ridge"), out_dir=tmp_path / "ridge"),
        MapperJob(split=one_pair, config=tiny_config("dm"), out_dir=tmp_path / "dm", name="dm on 1 pair"),
    ]
    with pytest.raises(UserError) as error:
        train_mappers(jobs, options=StageOptions(workers=2, progress=False))
    message = str(error.value)
    assert "mapper dm on 1 pair (1 training pairs" in message and "at least 2 training pairs" in message
    assert "\n" not in message and len(message) < 400 and "tensor" not in message


def test_resume_loads_instead_of_training(trained, split, monkeypatch):
    mapper, out_dir = trained["dm"]
    before = (out_dir / "curves.csv").stat().st_mtime_ns

    def no_training(*args, **kwargs):
        raise AssertionError("train_mapper trained although mapper.safetensors exists")

    monkeypatch.setattr(train_module, "_train", no_training)
    again = train_mapper(split, tiny_config("dm"), out_dir, progress=False)
    np.testing.assert_array_equal(again.map_batch(split.w_bc_val), mapper.map_batch(split.w_bc_val))
    assert (out_dir / "curves.csv").stat().st_mtime_ns == before
    with pytest.raises(UserError, match="made from other inputs \\(config.epochs: 40 -> 7\\)"):
        train_mapper(split, tiny_config("dm", epochs=7), out_dir, progress=False)
    with pytest.raises(UserError, match="made from other inputs \\(pairs: changed\\)"):
        train_mapper(synthetic_split(seed=1), tiny_config("dm"), out_dir, progress=False)


def test_rebuild_retrains_a_mapper_made_from_other_pairs(split, tmp_path):
    first = train_mapper(split, tiny_config("dm", epochs=2), tmp_path, progress=False)
    other = synthetic_split(seed=1)
    again = train_mapper(other, tiny_config("dm", epochs=2), tmp_path, rebuild=True, progress=False)
    assert again.stamp != first.stamp and load_mapper(tmp_path / "mapper.safetensors").stamp == again.stamp


def test_empty_validation_set(tmp_path):
    split = synthetic_split(n_train=20, n_val=0)
    train_mapper(split, tiny_config("dm", epochs=2), tmp_path, progress=False)
    rows = _curves(tmp_path)
    assert all(r["train_loss"] and not r["val_loss"] and not r["val_mse_weights"] for r in rows)


def test_user_errors(tmp_path, split):
    with pytest.raises(UserError, match="needs pistar_head"):
        train_mapper(split, tiny_config("pistar-head"), tmp_path / "a", progress=False)
    with pytest.raises(UserError, match="pistar_head has length 3, expected 12"):
        train_mapper(
            split, tiny_config("pistar-head"), tmp_path / "b", pistar_head=np.zeros(3, np.float32), progress=False
        )
    with pytest.raises(UserError, match="at least 2 training pairs"):
        train_mapper(synthetic_split(n_train=1, n_val=1), tiny_config("dm"), tmp_path / "c", progress=False)
    with pytest.raises(UserError, match="non-empty"):
        evaluate_mapping(Mapper.mean_da(split.w_da_train), split.w_bc_val, split.w_da_val[:3])


def test_paper_config_and_validation():
    assert (
        paper_config("dm").epochs == 500
        and paper_config("sam").epochs == 1000
        and paper_config("tam").ae_epochs == 1000
    )
    config = paper_config("tam", epochs=2000, latent=16)
    assert (
        config.epochs,
        config.latent,
        config.lr,
        config.weight_decay,
        config.ae_weight_decay,
        config.batch_size,
    ) == (2000, 16, 1e-4, 1e-4, 1e-5, 10)
    for kwargs, field in [
        (dict(kind="xyz"), "kind"),
        (dict(hidden=(8, 0)), "hidden"),
        (dict(hidden=[8]), "hidden"),
        (dict(latent=0), "latent"),
        (dict(dropout=1.0), "dropout"),
        (dict(ae_dropout=-0.1), "ae_dropout"),
        (dict(lr=0.0), "lr"),
        (dict(weight_decay=-1.0), "weight_decay"),
        (dict(batch_size=0), "batch_size"),
        (dict(epochs=0), "epochs"),
        (dict(batchnorm=1), "batchnorm"),
        (dict(seed=1.5), "seed"),
    ]:
        with pytest.raises(ValueError, match=f"MapperConfig.{field} "):
            MapperConfig(**kwargs)


def test_conditioned_reads_the_context_where_it_predicts_the_update(tmp_path):
    """Where w_DA depends on the seed's context, only the conditioned kind predicts that part;
    where it does not, cross-validation gives the context (almost) no weight."""
    informative = synthetic_split(context_effect=0.3)
    ridge = train_mapper(informative, tiny_config("ridge"), tmp_path / "ridge", progress=False)
    conditioned = train_mapper(informative, tiny_config("conditioned"), tmp_path / "conditioned", progress=False)
    args = (informative.w_bc_val, informative.w_da_val)
    with_context = evaluate_mapping(conditioned, *args, context=informative.context_val)["relative_mse"]
    assert with_context < 0.2 * evaluate_mapping(ridge, *args)["relative_mse"]
    assert conditioned.config["fit"]["context_weight"] > 0
    plain = synthetic_split()
    uninformed = train_mapper(plain, tiny_config("conditioned"), tmp_path / "plain", progress=False)
    ridge_plain = train_mapper(plain, tiny_config("ridge"), tmp_path / "ridge-plain", progress=False)
    args = (plain.w_bc_val, plain.w_da_val)
    assert (
        evaluate_mapping(uninformed, *args, context=plain.context_val)["mse"]
        <= 1.5 * evaluate_mapping(ridge_plain, *args)["mse"]
    )


def test_conditioned_needs_the_context(tmp_path, split):
    mapper = train_mapper(split, tiny_config("conditioned"), tmp_path / "a", progress=False)
    with pytest.raises(UserError, match="needs the seed's context beside w_BC"):
        mapper(split.w_bc_val[0].numpy())
    with pytest.raises(UserError, match=r"context has shape \(1, 3\), expected \(1, 4\)"):
        mapper(split.w_bc_val[0].numpy(), np.zeros(3, np.float32))
    bare = dataclasses.replace(split, context_train=None, context_val=None)
    with pytest.raises(UserError, match="stored without one; collect them again"):
        train_mapper(bare, tiny_config("conditioned"), tmp_path / "b", progress=False)


@pytest.mark.parametrize("kind", ["dm", "sam"])
def test_a_diverging_mapper_is_one_line_and_nothing_is_saved(tmp_path, split, kind):
    config = dataclasses.replace(tiny_config(kind), lr=1e30)
    with pytest.raises(
        DivergedError, match=rf"the {kind} mapper's network \w+ diverged at epoch \d+ of \d+ .*lower its learning rate"
    ):
        train_mapper(split, config, tmp_path / kind, progress=False)
    assert not list((tmp_path / kind).glob("*.safetensors"))


@pytest.mark.parametrize("kind", KINDS)
def test_training_and_mapping_call_no_kernel_whose_bits_depend_on_the_cpu(split, pistar_head, tmp_path, kind):
    """A mapper's training and its map reach none of MKL's vector math, whose bits depend on the CPU
    (docs/determinism.md): a mapper is the same on every x86-64 CPU."""

    def train_and_map() -> None:
        config = tiny_config(kind, epochs=2, ae_epochs=2)
        mapper = train_mapper(split, config, tmp_path, pistar_head=pistar_head, progress=False)
        mapper.map_batch(split.w_bc_val, split.context_val)

    assert mkl_vector_math_calls(train_and_map) == []

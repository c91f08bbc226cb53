"""The mapper-kind registry: every kind declared once; a new kind is its module plus one line."""

from __future__ import annotations

import pytest
import torch
from mapping_data import tiny_config
from torch import nn

from metadagger.errors import UserError
from metadagger.evaluation.benchmark.labels import method_label
from metadagger.evaluation.mdm import EvalConfig
from metadagger.mapping import registry
from metadagger.mapping.config import MapperConfig
from metadagger.mapping.mappers import load_mapper
from metadagger.mapping.registry import MapperKind, Route, get_kind, kind_names, register_kind
from metadagger.mapping.train import train_mapper
from metadagger.pipeline.run_config import resolve_config


def build_linear(dim: int, *, generator: torch.Generator | None = None, **_: object) -> dict[str, nn.Module]:
    """A toy learned kind: one linear map between standardised heads (its whole 'module')."""
    layer = nn.Linear(dim, dim)
    with torch.no_grad():
        layer.weight.copy_(torch.randn(dim, dim, generator=generator) * 0.01)
        layer.bias.zero_()
    return {"linear": layer}


LINEAR = MapperKind(
    "linear", "Linear", "toy: one linear map", route=Route("bc", None, "linear", None, "da"), build=build_linear
)


@pytest.fixture
def with_linear(monkeypatch):
    """The toy kind registered for one test, and removed after it."""
    monkeypatch.setattr(registry, "_KINDS", dict(registry._KINDS))
    register_kind(LINEAR)
    yield LINEAR


def test_builtin_kinds_and_their_declarations():
    assert kind_names() == ("dm", "sam", "tam", "ridge", "modes", "conditioned", "mean-da", "pistar-head")
    assert [get_kind(k).learned for k in kind_names()] == [True, True, True, True, True, True, False, False]
    assert [k for k in kind_names() if get_kind(k).context] == ["conditioned"]
    assert get_kind("tam").network_names == ("sigma_bc", "h", "sigma_da")
    assert get_kind("sam").scaler_names == ("all",) and get_kind("dm").paper_epochs == 500
    assert get_kind("conditioned").scaler_names == ("all", "context")
    assert method_label("sam") == "SAM" and method_label("oneshot-dm") == "one-shot DM"
    with pytest.raises(UserError, match="unknown mapper kind 'xyz': expected one of dm, sam"):
        get_kind("xyz")


def test_a_kind_is_either_learned_or_a_control():
    with pytest.raises(ValueError, match="either route and build"):
        MapperKind("half", "Half", "route without builder", route=Route("bc", None, "x", None, "da"))
    with pytest.raises(ValueError, match="closed-form fit needs a route without autoencoders"):
        MapperKind(
            "odd",
            "Odd",
            "closed form through a code",
            route=Route("all", "sigma_all", "h", "sigma_all", "all"),
            build=get_kind("sam").build,
            closed_form=get_kind("ridge").closed_form,
        )
    with pytest.raises(ValueError, match="a context needs a route without autoencoders"):
        MapperKind(
            "coded",
            "Coded",
            "context through a code",
            route=Route("all", "sigma_all", "h", "sigma_all", "all"),
            build=get_kind("sam").build,
            context=True,
        )


def test_a_new_kind_trains_saves_loads_and_is_known_everywhere(with_linear, split, tmp_path):
    assert "linear" in kind_names() and method_label("linear") == "Linear"
    config = MapperConfig(**{**tiny_config("dm").__dict__, "kind": "linear"})
    mapper = train_mapper(split, config, tmp_path, progress=False)
    loaded = load_mapper(tmp_path / "mapper.safetensors")
    assert loaded.kind == "linear"
    torch.testing.assert_close(
        torch.from_numpy(loaded.map_batch(split.w_bc_val)), torch.from_numpy(mapper.map_batch(split.w_bc_val))
    )
    # the evaluation and run configs accept it without any other change
    assert EvalConfig(methods=("linear", "mean-da")).methods == ("linear", "mean-da")
    run = resolve_config("carracing", "ci", overrides=["evaluate.methods=[linear]", "mappers={linear: {epochs: 2}}"])
    assert run.mapper_kinds == ("linear",) and run.mapper_config("linear").epochs == 2


def test_unregistered_kinds_are_refused_in_configs():
    with pytest.raises(UserError, match="evaluate.methods has unknown method"):
        EvalConfig(methods=("linear",))
    with pytest.raises(UserError, match="mappers has unknown kind"):
        resolve_config("carracing", "ci", overrides=["mappers={linear: {epochs: 2}}"])


def _installed(tmp_path, monkeypatch, package: str, entry: str) -> None:
    """A package installed beside metadagger whose only content is one ``metadagger.mappers`` entry point."""
    dist = tmp_path / f"{package.replace('-', '_')}-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {package}\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text(f"[metadagger.mappers]\n{entry}\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(registry, "_plugins_loaded", False)
    monkeypatch.setattr(registry, "_KINDS", dict(registry._KINDS))


def test_an_installed_package_adds_a_mapper_kind_through_its_entry_point(tmp_path, monkeypatch):
    (tmp_path / "mykinds.py").write_text(
        "from metadagger.mapping.registry import MapperKind\n"
        "ZERO = MapperKind('zero', 'Zero', 'control: always zeros', constant=lambda w, pistar: w[0] * 0)\n"
    )
    _installed(tmp_path, monkeypatch, "my-kinds", "zero = mykinds:ZERO")
    assert "zero" in kind_names() and method_label("mdm-zero") == "MDM Zero"


@pytest.mark.parametrize(
    "entry, says",
    [
        ("ghost = not_a_module:KIND", "fails to load (ModuleNotFoundError"),
        ("ghost = os:sep", "names a str, not a MapperKind"),
    ],
)
def test_a_broken_mapper_plug_in_is_one_line_naming_its_package(tmp_path, monkeypatch, entry, says):
    _installed(tmp_path, monkeypatch, "broken-kinds", entry)
    with pytest.raises(UserError, match="mapper plug-in 'ghost' of package broken-kinds") as info:
        get_kind("dm")
    assert says in str(info.value) and "fix or uninstall broken-kinds" in str(info.value)
    assert "\n" not in str(info.value)

import dataclasses
from typing import Literal

import pytest

from jaxcls.config import ConfigError, load_config, save_config


@dataclasses.dataclass(frozen=True)
class Inner:
    count: int = 3
    mode: Literal["a", "b"] = "a"


@dataclasses.dataclass(frozen=True)
class Outer:
    name: str = "x"
    radius: float = 1.0
    views: tuple[int, ...] = (0, 1)
    inner: Inner = dataclasses.field(default_factory=Inner)


def test_yaml_then_overrides_fill_a_frozen_dataclass(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("name: y\ninner:\n  count: 7\n")
    cfg = load_config(Outer, path, ["inner.mode=b", "radius=2.5"])
    assert cfg == Outer(name="y", radius=2.5, inner=Inner(count=7, mode="b"))
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.name = "z"


@dataclasses.dataclass(frozen=True)
class WithMapping:
    classifiers: dict[str, str] = dataclasses.field(default_factory=dict)
    inner: Inner = dataclasses.field(default_factory=Inner)


def test_a_mapping_override_replaces_the_mapping_and_a_block_override_merges(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("classifiers: {shipped: '', paper: builtin_paper}\ninner: {count: 7}\n")
    assert load_config(WithMapping, path, ["classifiers={paper: builtin_paper}"]).classifiers == {
        "paper": "builtin_paper"}
    assert load_config(WithMapping, path, ["classifiers.mine=w.msgpack"]).classifiers == {
        "shipped": "", "paper": "builtin_paper", "mine": "w.msgpack"}
    assert load_config(WithMapping, path, ["inner={mode: b}"]).inner == Inner(count=7, mode="b")


def test_defaults_without_file():
    assert load_config(Outer) == Outer()


@pytest.mark.parametrize(("text", "key"), [
    ("inner:\n  cuont: 7\n", "inner.cuont"),
    ("radius: far\n", "radius"),
    ("inner:\n  mode: c\n", "inner.mode"),
])
def test_bad_keys_and_types_name_the_key_and_file(tmp_path, text, key):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=rf"bad\.yaml.*{key}"):
        load_config(Outer, path)


def test_bad_override_names_the_key():
    with pytest.raises(ConfigError, match=r"command line.*inner\.count"):
        load_config(Outer, None, ["inner.count=many"])
    with pytest.raises(ConfigError, match=r"key\.sub=value"):
        load_config(Outer, None, ["radius"])


def test_missing_and_malformed_files(tmp_path):
    with pytest.raises(ConfigError, match=r"nope\.yaml.*not found"):
        load_config(Outer, tmp_path / "nope.yaml")
    path = tmp_path / "list.yaml"
    path.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match=r"list\.yaml.*mapping"):
        load_config(Outer, path)


def test_saved_config_loads_back_identically(tmp_path):
    cfg = Outer(name="q", radius=0.25, views=(4, 5, 6), inner=Inner(count=1, mode="b"))
    path = save_config(cfg, tmp_path / "run" / "config.yaml")
    assert load_config(Outer, path) == cfg


def test_absolute_thresholds_are_checked_against_the_volumes_voxels():
    from jaxcls.commands.run import RunConfig
    from jaxcls.perception.settings import PerceptionConfig, VolumeConfig

    PerceptionConfig(volume=VolumeConfig(resolution=256))  # finer voxels: the metres span more of them
    with pytest.raises(ConfigError, match=r"perception\.segmentation\.dbscan_eps = 0\.01 m is 1\.07 voxels.*"
                                          r"resolution 64 = 9\.4 mm.*set it to >= 0\.0141"):
        load_config(RunConfig, None, ["perception.volume.resolution=64"])
    load_config(RunConfig, None, ["perception.volume.resolution=64", "perception.segmentation.dbscan_eps=0.015"])
    with pytest.raises(ConfigError, match=r"perception\.foreground\.table_eps = 0\.004 m is 0\.85 voxels"):
        load_config(RunConfig, None, ["perception.foreground.table_eps=0.004"])


def test_a_retired_key_is_dropped_from_old_files_and_refused_from_the_command_line(tmp_path):
    from jaxcls.world.dataset import DatasetConfig

    old = tmp_path / "config.yaml"
    old.write_text("viewpoints:\n  count: 12\n  candidate_radius: 0.5\n")  # as every dataset saved it
    assert load_config(DatasetConfig, old).viewpoints.count == 12
    with pytest.raises(ConfigError, match=r"key 'viewpoints\.candidate_radius' is retired; use nbv\.radius"):
        load_config(DatasetConfig, None, ["viewpoints.candidate_radius=0.4"])

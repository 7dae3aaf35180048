"""Choices are typed: each an ``enum.StrEnum`` owned by the module that acts on it, set from YAML with errors
naming the key, acted on through its registry or member, never by comparing strings outside the config layer."""

from __future__ import annotations

import ast
import dataclasses
import enum
import importlib
import pkgutil
import warnings
from pathlib import Path

import pytest

import jaxcls
from jaxcls.config import ConfigError, load_config, to_yaml
from jaxcls.episode.setup import ActiveConfig
from jaxcls.perception.refine import RefineConfig, YawSource
from jaxcls.perception.settings import PerceptionConfig, Segmenter
from jaxcls.planning import nbv

PACKAGE = Path(jaxcls.__file__).parent
CONFIG_LAYER = {"config.py"}  # where a choice may meet its spelling


def _config_blocks() -> list[type]:
    """Every frozen config dataclass of the package (modules imported; the device-only ones skipped)."""
    blocks = []
    for info in pkgutil.walk_packages([str(PACKAGE)], "jaxcls."):
        try:
            module = importlib.import_module(info.name)
        except ImportError:  # a backend this machine lacks (MuJoCo Warp)
            continue
        blocks += [v for v in vars(module).values() if isinstance(v, type) and dataclasses.is_dataclass(v)
                   and v.__module__ == module.__name__]
    return blocks


def _choice_fields() -> set[str]:
    """Names of the config fields whose default is an enum member: the package's choices."""
    return {f.name for block in _config_blocks() for f in dataclasses.fields(block)
            if isinstance(f.default, enum.Enum)}


def _strings(node: ast.expr) -> bool:
    if isinstance(node, ast.Constant):
        return isinstance(node.value, str)
    return isinstance(node, ast.Tuple | ast.List | ast.Set) and all(_strings(e) for e in node.elts)


def _name(node: ast.expr) -> str | None:
    return node.attr if isinstance(node, ast.Attribute) else node.id if isinstance(node, ast.Name) else None


def test_the_package_has_choices_and_none_is_compared_as_a_string():
    choices = _choice_fields()
    assert {"policy", "segmenter", "yaw_source", "decision", "history", "mode", "prune_per"} <= choices
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if path.name in CONFIG_LAYER:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, ast.Compare):
                continue
            operands = [node.left, *node.comparators]
            if any(_strings(o) for o in operands) and any(_name(o) in choices for o in operands):
                found.append(f"{path.relative_to(PACKAGE.parent)}:{node.lineno}: {ast.unparse(node)}")
    assert not found, "choices compared as strings:\n" + "\n".join(found)


def test_yaml_spells_every_choice_as_its_value_and_reads_back():
    settings = load_config(ActiveConfig, None, ["perception.segmenter=reference", "refine.yaw_source=learned",
                                                "episode.policy=continuous", "nbv.history=max",
                                                "perception.tracking.mode=reported", "refine.prune_per=class"])
    assert settings.perception.segmenter is Segmenter.reference
    assert settings.refine.yaw_source is YawSource.learned and settings.episode.policy is nbv.PolicyName.continuous
    text = to_yaml(settings)
    assert "segmenter: reference" in text and "prune_per: class" in text and "policy: continuous" in text
    again = load_config(ActiveConfig, None, [f"{k}={v}" for k, v in (("perception.segmenter", "reference"),)])
    assert again.perception.segmenter is Segmenter.reference


@pytest.mark.parametrize("key, value", [("perception.segmenter", "sklearn"), ("refine.yaw_source", "learnt"),
                                        ("episode.policy", "best"), ("nbv.vis_occl_hist_unc.uncertainty", "margin"),
                                        ("episode.decision", "vote"), ("perception.tracking.mode", "none")])
def test_a_wrong_choice_from_yaml_names_the_key_and_the_choices(key, value):
    with pytest.raises(ConfigError, match=rf"{key.replace('.', r'[.]')}.*Invalid value '{value}', expected one of"):
        load_config(ActiveConfig, None, [f"{key}={value}"])


def test_a_wrong_choice_from_python_names_the_field_and_a_right_one_becomes_the_member():
    with pytest.raises(ValueError, match=r"refine\.yaw_source must be one of \['hypotheses', 'learned', 'auto'\], "
                                         r"got 'learnt'"):
        RefineConfig(yaw_source="learnt")
    with pytest.raises(ValueError, match=r"perception\.segmenter must be one of"):
        PerceptionConfig(segmenter="sklearn")
    assert RefineConfig(yaw_source="learned").yaw_source is YawSource.learned


def test_policies_carry_their_parameters_from_the_nbv_block():
    settings = load_config(ActiveConfig, None, ["episode.policy=continuous", "nbv.continuous.steps=5",
                                                "nbv.continuous.starts=2", "nbv.info_gain.gain.step_voxels=3.0"])
    chosen = settings.nbv.policy(settings.episode.policy)
    assert isinstance(chosen, nbv.Continuous) and (chosen.steps, chosen.starts) == (5, 2)
    assert settings.nbv.policy("info_gain").gain.step_voxels == 3.0
    assert nbv.policy("random") == nbv.Random() and set(nbv.POLICIES) == set(nbv.PolicyName)
    with pytest.raises(ConfigError, match=r"nbv\.continuous\.steps"):
        load_config(ActiveConfig, None, ["nbv.continuous.steps=0"])


def test_the_yaw_source_is_resolved_for_the_weights_and_says_so():
    auto = RefineConfig(yaw_source="auto", hypotheses=2)
    assert auto.resolve(yaw_head=True).yaw_source is YawSource.learned
    with pytest.warns(UserWarning, match=r"no yaw head, so GR registers 2 evenly spaced yaws"):
        ran = auto.resolve(yaw_head=False, weights="paper.msgpack")
    assert ran.yaw_source is YawSource.hypotheses and ran.hypotheses == 2
    with pytest.raises(ValueError, match=r"yaw_source=learned needs weights with a yaw head; paper\.msgpack"):
        RefineConfig(yaw_source="learned").resolve(yaw_head=False, weights="paper.msgpack")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert RefineConfig(yaw_source="hypotheses").resolve(yaw_head=False).yaw_source is YawSource.hypotheses


def test_weights_without_a_yaw_head_make_an_episode_that_says_which_yaws_ran():
    """The episode keeps the resolved yaw source (what ``jaxcls run`` saves in its config.yaml): weights
    without a yaw head run, and say, evenly spaced hypotheses."""
    from jaxcls.episode import setup
    from jaxcls.geometry import Intrinsics
    from jaxcls.perception import pointnet
    from jaxcls.world.objects import builtin_object_set

    paper = pointnet.load_classifier("builtin_paper")
    assert not paper.config.yaw_head
    settings = setup.ActiveConfig(refine=dataclasses.replace(setup.episode_refine(), yaw_source="auto"))
    with pytest.warns(UserWarning, match="no yaw head"):
        episode = setup.make_episode(settings, builtin_object_set(), Intrinsics.kinect_v1(), 0.0, paper)
    assert episode.refine_config.yaw_source is YawSource.hypotheses

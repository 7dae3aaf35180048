"""The ``jaxcls`` commands as a newcomer meets them: from any folder, with plain help, clear errors, figures
that can be read. Scenes are small (160x120 camera, one view) so that each test takes seconds."""

import dataclasses
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import jaxcls
from jaxcls import cli, viz
from jaxcls.config import ConfigError, load_config
from jaxcls.world import scenes
from jaxcls.world.dataset import DatasetConfig
from jaxcls.world.objects import ObjectSetConfig

CAMERA = ["camera.width=160", "camera.height=120", "camera.fx=131.25", "camera.fy=131.25", "camera.cx=79.5",
          "camera.cy=59.5"]
SMALL_SHOW = [*CAMERA, "views=[0]", "viewpoints.count=4"]  # backend: auto, as a user runs it
SMALL_DATASET = [*CAMERA, "num_scenes=1", "viewpoints.count=2", "backend=mujoco"]
_SCRIPT = Path(sys.executable).with_name("jaxcls")
JAXCLS = [str(_SCRIPT)] if _SCRIPT.is_file() else [sys.executable, "-m", "jaxcls.cli"]


def run_jaxcls(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    """``jaxcls args...`` as a user types it, in ``cwd`` (this checkout's package first on the path)."""
    repo = str(Path(jaxcls.__file__).resolve().parent.parent)
    env = {**os.environ, "JAX_PLATFORMS": os.environ.get("JAX_PLATFORMS", "cpu"),
           "PYTHONPATH": os.pathsep.join(p for p in (repo, os.environ.get("PYTHONPATH")) if p)}
    return subprocess.run([*JAXCLS, *args], cwd=cwd, capture_output=True, text=True, env=env, timeout=300)


# ---------------------------------------------------------------------------------------------- any folder

def test_commands_run_outside_the_repository(tmp_path):
    """Shipped configs are package data: by name or as configs/<name>.yaml, from any folder."""
    done = run_jaxcls("dataset", "--config", "synthetic", *SMALL_DATASET, f"out_dir={tmp_path / 'd'}", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert sorted(p.name for p in (tmp_path / "d").iterdir()) == ["config.yaml", "scene_000.npz"]

    done = run_jaxcls("show", "--config", "configs/synthetic.yaml", *SMALL_SHOW, f"out_dir={tmp_path / 's'}",
                      cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "s" / "scene.png").is_file() and str(tmp_path / "s" / "scene.png") in done.stdout
    output = done.stdout + done.stderr
    assert "Failed to import warp" not in output  # no GPU here: the CPU path says nothing about warp
    assert "Traceback" not in output

    done = run_jaxcls("train", "--print-config", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert "name: pointnet_builtin" in done.stdout  # the default config, pointnet.yaml
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d", "s"]  # nothing written elsewhere


# ---------------------------------------------------------------------------------------------- help

def test_top_help_is_plain_text_listing_the_commands(capsys):
    with pytest.raises(SystemExit) as done:
        cli.main(["--help"])
    assert done.value.code == 0
    out = capsys.readouterr().out
    assert all(name in out for name in cli.COMMANDS)
    assert "``" not in out and ":func:" not in out and ":class:" not in out


def test_version(capsys):
    with pytest.raises(SystemExit) as done:
        cli.main(["--version"])
    assert done.value.code == 0
    assert capsys.readouterr().out.strip() == f"jaxcls {jaxcls.__version__}"


@pytest.mark.parametrize("name", list(cli.COMMANDS))
def test_command_help_is_plain_and_its_example_is_valid(name, capsys):
    with pytest.raises(SystemExit) as done:
        cli.main([name, "--help"])
    assert done.value.code == 0
    out = capsys.readouterr().out
    assert f"jaxcls {name}" in out and "``" not in out
    command = cli.COMMANDS[name].load()
    if command.schema is None:
        return
    if name == "train":
        assert "scene." not in out  # train has no scene key
    assert command.example and command.example in " ".join(out.split())
    load_config(command.schema, overrides=command.example.split())
    if command.default_config:
        load_config(command.schema, command.default_config, overrides=command.example.split())


# ---------------------------------------------------------------------------------------------- jaxcls show

def test_show_previews_the_sensor_of_a_dataset_config(tmp_path, monkeypatch, capsys):
    figures = []
    save = viz.save
    monkeypatch.setattr(viz, "save", lambda figure, path, **kw: (figures.append(figure), save(figure, path, **kw))[1])
    out = tmp_path / "real"
    assert cli.main(["show", "--config", "real_like", *SMALL_SHOW, f"out_dir={out}"]) == 0
    assert (out / "scene.png").is_file()
    from jaxcls.commands.show import ShowConfig

    saved = load_config(ShowConfig, out / "config.yaml")
    assert saved.sensor == load_config(DatasetConfig, "real_like").sensor
    assert saved.sensor.axial_noise and saved.sensor.pose_noise
    titles = [ax.get_title() for figure in figures for ax in figure.axes]
    assert any("sensor depth" in t for t in titles), titles


def test_show_keeps_an_earlier_run_unless_overwrite(tmp_path, capsys):
    out = tmp_path / "show"
    assert cli.main(["show", *SMALL_SHOW, f"out_dir={out}"]) == 0
    assert str(out / "scene.png") in capsys.readouterr().out
    first = (out / "scene.json").read_text()
    assert cli.main(["show", *SMALL_SHOW, "seed=1", f"out_dir={out}"]) == 0
    second = tmp_path / "show-2"
    assert str(second / "scene.png") in capsys.readouterr().out  # says where it went
    assert (out / "scene.json").read_text() == first and (second / "scene.png").is_file()
    assert cli.main(["show", *SMALL_SHOW, "seed=1", f"out_dir={out}", "--overwrite"]) == 0
    assert str(out / "scene.png") in capsys.readouterr().out
    assert (out / "scene.json").read_text() != first
    assert not (tmp_path / "show-3").exists()


def test_show_scene_file_refuses_a_seed(tmp_path, capsys):
    out = tmp_path / "show"
    assert cli.main(["show", *SMALL_SHOW, f"out_dir={out}"]) == 0
    capsys.readouterr()
    code = cli.main(["show", f"scene_file={out / 'scene.json'}", "seed=99", *SMALL_SHOW,
                     f"out_dir={tmp_path / 'again'}"])
    err = capsys.readouterr().err
    assert code == 2 and "seed" in err and "Traceback" not in err


def test_show_of_a_dataset_config_does_not_write_into_the_dataset_folder(tmp_path, monkeypatch, capsys):
    """A borrowed dataset config lends its world only: show writes to its own out_dir, and a saved scene
    can be previewed through that world's sensor (the file's scene settings are not command-line ones)."""
    monkeypatch.chdir(tmp_path)
    assert cli.main(["show", "--config", "real_like", *SMALL_SHOW]) == 0
    assert not (tmp_path / "data" / "real_like").exists() and (tmp_path / "runs" / "show" / "scene.png").is_file()
    assert cli.main(["show", "--config", "real_like", f"scene_file={tmp_path / 'runs' / 'show' / 'scene.json'}",
                     *SMALL_SHOW, f"out_dir={tmp_path / 'again'}"]) == 0


# ---------------------------------------------------------------------------------------------- errors

def test_ctrl_c_says_how_to_resume(monkeypatch, tmp_path, capsys):
    def interrupted(config, args):
        raise KeyboardInterrupt

    entry = cli.COMMANDS["dataset"]
    patched = cli.Entry(entry.summary, lambda: dataclasses.replace(entry.load(), run=interrupted))
    monkeypatch.setitem(cli.COMMANDS, "dataset", patched)
    assert cli.main(["dataset", *SMALL_DATASET, f"out_dir={tmp_path / 'd'}"]) == 130
    err = capsys.readouterr().err
    assert "interrupted: run the same command again to resume" in err and "Traceback" not in err


def test_bad_override_names_the_key(tmp_path, capsys):
    code = cli.main(["dataset", "sensor.random_dropout=1.5", f"out_dir={tmp_path / 'd'}"])
    err = capsys.readouterr().err
    assert code == 2 and "sensor.random_dropout" in err and "Traceback" not in err
    assert not (tmp_path / "d").exists()


def test_export_onto_an_existing_folder_names_the_flag(tmp_path, capsys):
    assert cli.main(["dataset", "--config", "synthetic", *SMALL_DATASET, f"out_dir={tmp_path / 'd'}"]) == 0
    npz, folder = str(tmp_path / "d" / "scene_000.npz"), str(tmp_path / "rec")
    assert cli.main(["export", npz, folder]) == 0
    capsys.readouterr()
    assert cli.main(["export", npz, folder]) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert cli.main(["export", npz, folder, "--overwrite"]) == 0


# ---------------------------------------------------------------------------------------------- figures

def test_scene_figure_of_twelve_classes_has_twelve_colours_and_a_legend():
    classes = [f"class_{i:02d}" for i in range(12)]
    objects = tuple(scenes.PlacedObject(name=f"{c}_a", class_name=c, position=(0.1 * (i % 4), 0.1 * (i // 4)),
                                        yaw=0.0) for i, c in enumerate(classes))
    scene = scenes.Scene(objects=objects, object_set=ObjectSetConfig())
    colours = viz.class_colours(classes)
    assert len(set(colours.values())) == 12
    T_wc = np.stack([np.eye(4)] * 3)
    T_wc[:, :3, 3] = [[0, 0, 1], [1, 0, 1], [0, 1, 1]]
    ids = np.arange(12 * 16).reshape(12, 16) % 13 - 1  # every object and the table
    figure = viz.plot_scene(scene, T_wc, [0], np.ones((1, 12, 16)), ids[None])
    legends = [ax.get_legend() for ax in figure.axes if ax.get_legend() is not None]
    labels = {t.get_text() for legend in legends for t in legend.get_texts()}
    assert set(classes) <= labels


def test_confusion_axes_are_labelled():
    counts = np.array([[3, 1], [0, 4]])
    figure = viz.confusion({"full": counts, "view": counts}, ["mug", "can"])
    for ax in figure.axes:
        assert ax.get_xlabel() == "predicted class" and ax.get_ylabel() == "true class"


def test_training_curve_ticks_are_whole_epochs():
    history = [{"epoch": e, "loss": 1.0 / e, "train_accuracy": 0.5 + 0.1 * e,
                "test_accuracy": {"full": 0.4 + 0.1 * e, "view": 0.3 + 0.1 * e}} for e in (1, 2, 3)]
    figure = viz.training_curve(history)
    for ax in figure.axes:
        lo, hi = ax.get_xlim()
        ticks = [t for t in ax.get_xticks() if lo <= t <= hi]
        assert ticks and np.allclose(ticks, np.round(ticks)), ticks


def test_show_reads_only_the_world_of_a_dataset_config_and_its_own_configs_whole(tmp_path, monkeypatch, capsys):
    """A dataset config lends show its world (said on stderr), never its out_dir or seed; a show config
    with a dataset-only key is an error naming it, not silently a dataset config."""
    monkeypatch.chdir(tmp_path)
    from jaxcls.commands import show

    command = show.COMMAND
    config = cli.load_command_config("show", command, "real_like", [])
    assert config.out_dir == "runs/show" and config.seed == 0 and config.sensor.axial_noise
    assert "reading its world only" in capsys.readouterr().err
    own = tmp_path / "mine.yaml"
    own.write_text("out_dir: here\nviews: [1]\nnum_scenes: 3\n")
    with pytest.raises(ConfigError, match="num_scenes"):
        cli.load_command_config("show", command, str(own), [])


def test_show_refuses_an_out_dir_without_a_name_before_rendering(capsys):
    assert cli.main(["show", "out_dir=/", *SMALL_SHOW]) == 2
    assert "out_dir" in capsys.readouterr().err

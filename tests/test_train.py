"""Training clouds and ``jaxcls train``: clouds lie on the rendered instance, batches are subsets turned
about z, the cache resumes, a short CPU run learns, is deterministic, resumes to the same result, and
splits its batch over several (forced host) devices with the same losses."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial import cKDTree

from jaxcls.cli import main as cli_main
from jaxcls.config import load_config
from jaxcls.learn import clouds
from jaxcls.learn.logs import read_scalars
from jaxcls.learn.train import Mix, TrainConfig, train
from jaxcls.perception.settings import PerceptionConfig
from jaxcls.world.objects import ObjectSetConfig, builtin_object_set

TINY_OBJECTS = ObjectSetConfig(train_per_class=1, test_per_class=1, surface_samples=2500)


def _tiny_config(tmp: Path, **changes) -> TrainConfig:
    data = clouds.CloudConfig(views_per_instance=2, occluded_per_instance=0, fused_per_instance=0,
                              image_scale=0.25, max_points=256, backend="mujoco", cache_dir=str(tmp / "cache"))
    config = TrainConfig(name="tiny", out_dir=str(tmp / "run"), objects=TINY_OBJECTS, data=data,
                         mix=Mix(full=0.5, view=0.5), model=dataclasses.replace(TrainConfig().model, num_points=64),
                         epochs=4, steps_per_epoch=5, batch_size=8, learning_rate=3e-4, eval_rotations=2,
                         eval_batch=32)
    return dataclasses.replace(config, **changes)


@pytest.fixture(scope="module")
def workspace(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("train")


@pytest.fixture(scope="module")
def straight_run(workspace) -> Path:
    """Four epochs in one go (the cache it fills is shared by the other runs)."""
    return train(_tiny_config(workspace, out_dir=str(workspace / "straight")), show_progress=False)


def _history(run: Path) -> list[dict]:
    return json.loads((run / "metrics.json").read_text())["history"]


def test_view_clouds_lie_on_the_posed_instance():
    object_set = builtin_object_set(train_per_class=1, test_per_class=0)
    model = object_set.train[0]
    config = clouds.CloudConfig(image_scale=0.5, backend="mujoco")
    maker = clouds._InstanceRenderer(model, object_set.train, TINY_OBJECTS, config, np.random.default_rng(0),
                                      PerceptionConfig())
    renderer, index, centre, pose = maker._scene(object_set.train[1:3])
    found, _ = maker._views(renderer, index, centre, 3)
    assert len(found) == 3
    dense = model.mesh.sample(200_000, seed=0) @ pose[:3, :3].T + pose[:3, 3]
    for points in found:
        assert len(points) >= config.min_points
        assert np.all(points[:, 2] > maker.table_top)
        distance, _ = cKDTree(dense).query(points)
        assert np.percentile(distance, 95) < 2e-3, np.percentile(distance, 95)


def test_sample_batch_draws_real_points_turned_about_z():
    rng = np.random.default_rng(0)
    points = rng.normal(size=(3, 50, 3)).astype(np.float32)
    mask = np.zeros((3, 50), bool)
    mask[0, :50], mask[1, :10], mask[2, :30] = True, True, True
    index = jnp.asarray([0, 1, 2, 1])
    out, m = clouds.sample_batch(jax.random.key(0), jnp.asarray(points), jnp.asarray(mask), index, 20)
    np.testing.assert_array_equal(np.sum(m, 1), [20, 10, 20, 10])
    for row, source in enumerate([0, 1, 2, 1]):
        real = np.asarray(out[row])[np.asarray(m[row])]
        original = points[source][mask[source]]
        # a yaw keeps z and the distance to the z axis: match each drawn point to its original by those
        key = np.stack([original[:, 2], np.linalg.norm(original[:, :2], axis=1)], 1)
        drawn = np.stack([real[:, 2], np.linalg.norm(real[:, :2], axis=1)], 1)
        distance, which = cKDTree(key).query(drawn)
        assert np.all(distance < 1e-5) and len(set(which)) == len(which)  # distinct real points


def test_cache_resumes_without_rendering(workspace, straight_run, monkeypatch):
    config = _tiny_config(workspace)
    object_set = builtin_object_set(train_per_class=1, test_per_class=1, surface_samples=2500)
    first = clouds.load_clouds(object_set, "test", config.data, config.objects, config.seed, show_progress=False)
    monkeypatch.setattr(clouds, "instance_clouds", lambda *a, **k: pytest.fail("rendered again"))
    again = clouds.load_clouds(object_set, "test", config.data, config.objects, config.seed, show_progress=False)
    np.testing.assert_array_equal(first.points, again.points)
    assert set(first.source) == {0, 1} and set(first.label) == set(range(8))


def test_short_run_learns_and_writes_its_outputs(straight_run):
    history = _history(straight_run)
    assert [h["epoch"] for h in history] == [1, 2, 3, 4]
    # 20 steps of batch 8 from 8 classes: well above chance (1/8) by the end, the loss below its start
    assert np.mean([h["train_accuracy"] for h in history[-2:]]) > 2.5 / 8
    assert min(h["loss"] for h in history[-2:]) < history[0]["loss"]
    metrics = json.loads((straight_run / "metrics.json").read_text())
    assert set(metrics["final"]) == {"full", "view"}
    assert set(metrics["final"]["full"]["per_class"]) == set(metrics["classes"])
    assert np.sum(metrics["final"]["full"]["confusion"]) == 8 * 2  # 8 held-out instances x 2 yaws
    for name in ("curve.png", "confusion.png", "pointnet.msgpack", "pointnet.json", "config.yaml"):
        assert (straight_run / name).stat().st_size > 0
    # The same history as TensorBoard reads it from the run's event files (float32 there)
    logged = read_scalars(straight_run / "tensorboard")
    for name in ("loss", "train_accuracy", "test_accuracy/full", "test_accuracy/view", "learning_rate"):
        want = {h["epoch"]: (h[name.split("/")[0]][name.split("/")[1]] if "/" in name else h[name]) for h in history}
        assert logged[name] == pytest.approx(want, rel=1e-6), name


def test_same_seed_same_weights_and_resume_matches(workspace, straight_run):
    again = train(_tiny_config(workspace, out_dir=str(workspace / "again")), show_progress=False)
    assert (again / "pointnet.msgpack").read_bytes() == (straight_run / "pointnet.msgpack").read_bytes()
    # Interrupted after two epochs, then the same command resumes from the checkpoint.
    resumed = workspace / "resumed"
    train(_tiny_config(workspace, out_dir=str(resumed), epochs=2), show_progress=False)
    train(_tiny_config(workspace, out_dir=str(resumed)), show_progress=False)
    assert [h["loss"] for h in _history(resumed)] == [h["loss"] for h in _history(straight_run)]
    assert read_scalars(resumed / "tensorboard")["loss"] == read_scalars(straight_run / "tensorboard")["loss"]
    assert (resumed / "pointnet.msgpack").read_bytes() == (straight_run / "pointnet.msgpack").read_bytes()


def test_config_errors_name_the_problem(workspace):
    with pytest.raises(ValueError, match=r"mix\.occluded"):
        train(_tiny_config(workspace, out_dir=str(workspace / "bad"), mix=Mix(full=1.0, occluded=1.0)),
              show_progress=False)
    with pytest.raises(ValueError, match="mix weights"):
        _tiny_config(workspace, mix=Mix(full=0.0))
    assert cli_main(["train", "--config", "configs/pointnet.yaml", "batch_size=0"]) == 2


def test_data_parallel_over_four_host_devices(workspace):
    """The batch split over 4 forced host devices: the compiled epoch all-reduces, two steps give the same
    losses as on one device, and ``train`` runs there: with one step an epoch, its first loss (before any update)
    is the one-device run's. (Later steps drift apart as the sums' order differs and Adam amplifies it: after five
    steps the first epoch's mean loss differed by 4%, with jax 0.10.2, flax 0.12.8 and optax 0.2.8.)"""
    one_step = {"steps_per_epoch": 1, "epochs": 1}
    single = train(_tiny_config(workspace, out_dir=str(workspace / "single"), **one_step), show_progress=False)
    script = textwrap.dedent(f"""
        import dataclasses, json, sys
        from pathlib import Path
        import jax
        import numpy as np
        from jax.sharding import Mesh, NamedSharding, PartitionSpec
        sys.path.insert(0, {str(Path(__file__).parent)!r})
        from test_train import _tiny_config
        from jaxcls.learn.clouds import CloudSet
        from jaxcls.learn.train import create_state, make_bank, make_train_epoch, train
        assert jax.device_count() == 4, jax.devices()
        config = _tiny_config(Path({str(workspace)!r}), out_dir={str(workspace / "parallel")!r}, **{one_step!r})
        rng = np.random.default_rng(0)
        fake = CloudSet(rng.normal(size=(8, 64, 3)).astype(np.float32), np.ones((8, 64), bool),
                        np.arange(8, dtype=np.int32), np.zeros(8, np.int32), np.zeros(8, np.int32),
                        np.zeros(8, np.float32))
        out = {{}}
        for n in (1, 4):
            mesh = Mesh(np.asarray(jax.devices()[:n]), ("data",))
            replicated = NamedSharding(mesh, PartitionSpec())
            epoch = make_train_epoch(config, 8, 2, mesh)
            args = (jax.device_put(create_state(config, 8, 2), replicated),
                    jax.device_put(make_bank(fake, dataclasses.replace(config.mix, view=0.0)), replicated),
                    jax.random.key(0))
            if n == 4:
                assert "all-reduce" in epoch.lower(*args).compile().as_text()
            state, metrics = epoch(*args)
            out[n] = np.asarray(metrics["loss"])  # the second step's loss follows the first update
        # Summed in another order over 4 devices; Adam's first step (g / |g|) amplifies the rounding.
        np.testing.assert_allclose(out[4], out[1], rtol=2e-4)
        run = train(config, show_progress=False)
        print(json.dumps([h["loss"] for h in json.loads((run / "metrics.json").read_text())["history"]]))
    """)
    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=4", "JAX_PLATFORMS": "cpu"}
    result = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=600,
                            cwd=Path(__file__).parent.parent)
    assert result.returncode == 0, result.stderr[-3000:]
    losses = json.loads(result.stdout.strip().splitlines()[-1])
    assert len(losses) == 1 and np.all(np.isfinite(losses))
    assert losses[0] == pytest.approx(_history(single)[0]["loss"], rel=2e-4)


def test_training_on_a_model_folder(tmp_path):
    """A user's folder of class subfolders trains the same way; without held-out instances the error says
    how to get some."""
    import trimesh

    shapes = {"ball": lambda s: trimesh.creation.icosphere(radius=0.04 * s),
              "crate": lambda s: trimesh.creation.box((0.08 * s, 0.06, 0.05)),
              "tube": lambda s: trimesh.creation.cylinder(radius=0.03, height=0.12 * s)}
    for name, make in shapes.items():
        (tmp_path / "models" / name).mkdir(parents=True)
        for i, s in enumerate((0.9, 1.0, 1.1)):
            make(s).export(tmp_path / "models" / name / f"{i}.stl")
    small = [f"out_dir={tmp_path / 'run'}", f"data.cache_dir={tmp_path / 'cache'}", "epochs=1", "steps_per_epoch=2",
             "batch_size=8", "model.num_points=64", "eval_batch=16", "eval_rotations=2", "objects.surface_samples=600",
             "data.full_points=600", "data.views_per_instance=1", "data.occluded_per_instance=0",
             "data.fused_per_instance=0", "data.image_scale=0.25", "mix.occluded=0", "mix.fused=0", "data.scenes=2",
             "data.scene_max_views=2"]
    command = ["train", "--config", "configs/pointnet_folder.yaml", f"objects.source={tmp_path / 'models'}", *small]
    assert cli_main(command) == 0  # the README's command
    run = tmp_path / "run"
    info = json.loads((run / "pointnet.json").read_text())
    assert info["classes"] == ["ball", "crate", "tube"]
    final = json.loads((run / "metrics.json").read_text())["final"]
    assert final["full"]["count"] == 3 * 2  # 1 held-out instance per class x 2 yaws
    # Resuming with other settings, or with another class list, is refused (not mixed into the run).
    with pytest.raises(ValueError, match="learning_rate"):
        train(load_config(TrainConfig, "configs/pointnet_folder.yaml",
                          [f"objects.source={tmp_path / 'models'}", *small, "learning_rate=0.01"]), show_progress=False)
    (tmp_path / "models" / "tube").rename(tmp_path / "models" / "pipe")
    with pytest.raises(ValueError, match="holds a run on classes"):  # same settings (a cosine run's epochs too)
        train(load_config(TrainConfig, "configs/pointnet_folder.yaml",
                          [f"objects.source={tmp_path / 'models'}", *small]), show_progress=False)


def test_training_does_not_need_mujoco():
    """``jaxcls train`` runs where MuJoCo is absent (the GPU machine) once its clouds are cached."""
    code = "import sys, jaxcls.cli, jaxcls.learn.train; sys.exit('mujoco' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code], timeout=120).returncode == 0


def test_yaw_orders_and_the_yaw_loss():
    """The head's order per class is the lcm of its instances' finite orders (0 if all are continuous);
    its loss is 0 at the target, blind to a turn by 2 pi / s, and ignores continuous classes."""
    from jaxcls.learn.train import yaw_loss
    from jaxcls.perception import pointnet

    assert pointnet.yaw_orders([[2, 4], [0, 0], [1, 0], [2, 2]]) == (4, 0, 1, 2)
    orders = jnp.array([4, 0, 1], jnp.int32)
    labels = jnp.array([0, 1, 2])
    yaw = jnp.array([0.3, 1.0, -2.0])
    s = np.array([4.0, 0.0, 1.0])
    target = np.stack([np.cos(s * yaw), np.sin(s * yaw)], -1)
    head = np.zeros((3, 3, 2), np.float32)
    head[np.arange(3), labels] = target
    head[1, 1] = [5.0, 5.0]  # a continuous class: whatever the head says costs nothing
    assert float(yaw_loss(jnp.asarray(head), labels, yaw, orders)) == pytest.approx(0.0, abs=1e-10)
    turned = yaw + 2 * np.pi / np.maximum(s, 1)
    assert float(yaw_loss(jnp.asarray(head), labels, turned, orders)) == pytest.approx(0.0, abs=1e-8)
    assert float(yaw_loss(jnp.asarray(head), labels, yaw + 0.2, orders)) > 0.01
    quarter_turn = np.array([[0.0, -1, 0, 0.2], [1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    assert clouds._yaw(quarter_turn) == pytest.approx(np.pi / 2)


def test_a_yaw_head_trains_and_feeds_refinement(workspace):
    """``model.yaw_head``: training records the head's error on held-out clouds, the weights carry the
    classes' orders, ``estimate_yaw`` gives [N, M] (0 for continuous classes), and GR's learned mode takes it
    (and refuses to run without it)."""
    from jaxcls.perception import pointnet, refine

    config = _tiny_config(workspace, out_dir=str(workspace / "yaw"), epochs=2)
    config = dataclasses.replace(config, model=dataclasses.replace(config.model, yaw_head=True))
    run = train(config, show_progress=False)
    final = json.loads((run / "metrics.json").read_text())["final"]
    assert final["view"]["yaw_error_deg"]["count"] > 0 and 0 <= final["view"]["yaw_error_deg"]["median"] <= 180
    classifier = pointnet.load_classifier(run / "pointnet.msgpack")
    object_set = builtin_object_set(train_per_class=1, test_per_class=1)
    assert classifier.yaw_orders == pointnet.yaw_orders([[m.yaw_symmetry for m in object_set.train
                                                          if m.class_name == c] for c in classifier.classes])
    rng = np.random.default_rng(0)
    points = rng.normal(0, 0.03, (2, 64, 3)).astype(np.float32)
    mask = np.ones((2, 64), bool)
    yaw = np.asarray(pointnet.estimate_yaw(classifier, points, mask))
    orders = np.asarray(classifier.yaw_orders)
    assert yaw.shape == (2, len(classifier.classes)) and np.all(yaw[:, orders == 0] == 0)
    assert np.all(np.abs(yaw) <= np.pi / np.maximum(orders, 1) + 1e-6)
    library = refine.ModelLibrary.build(object_set.test, classifier.classes)
    rc = refine.RefineConfig(yaw_source="learned", hypotheses=3, prune_after=2, icp=refine.icp.ICPConfig(iterations=4))
    probs = np.full((2, len(classifier.classes)), 1.0 / len(classifier.classes), np.float32)
    out = refine.refine_jit(points, mask, probs, library, rc, 0.0, None, yaw, orders)
    assert np.all(np.isfinite(np.asarray(out.pose)))
    with pytest.raises(ValueError, match="learned"):
        refine.refine_jit(points, mask, probs, library, rc, 0.0)
    with pytest.raises(ValueError, match="no yaw head"):
        pointnet.estimate_yaw(pointnet.load_classifier("builtin_paper"), points, mask)


def test_the_learning_rate_schedules():
    """halving: the paper's staircase; cosine: from the rate down a half cosine to final_lr of it, never lower."""
    from jaxcls.learn.train import Schedule, learning_rate

    steps = 7
    halving = learning_rate(TrainConfig(epochs=100, lr_halving_epochs=20, learning_rate=1e-3), steps)
    for epoch in (0, 19, 20, 45, 99):
        assert float(halving(epoch * steps)) == pytest.approx(1e-3 * 0.5 ** (epoch // 20), rel=1e-6)
    cosine = learning_rate(TrainConfig(epochs=40, schedule=Schedule.cosine, final_lr=0.01, learning_rate=1e-3),
                           steps)
    rates = np.array([float(cosine(s)) for s in range(40 * steps + 1)])
    assert rates[0] == pytest.approx(1e-3) and rates[-1] == pytest.approx(1e-5, rel=1e-4)
    assert rates[20 * steps] == pytest.approx(1e-5 + (1e-3 - 1e-5) / 2, rel=1e-4)  # half way: the mean
    assert np.all(np.diff(rates) <= 0) and rates.min() >= 1e-5 * (1 - 1e-5)
    assert load_config(TrainConfig, "pointnet_folder").schedule is Schedule.cosine
    with pytest.raises(Exception, match="schedule"):
        load_config(TrainConfig, None, ["schedule=linear"])


def test_a_cosine_run_logs_its_rate_and_held_out_loss_and_refuses_a_longer_resume(workspace, straight_run):
    from sklearn.metrics import log_loss

    from jaxcls.learn.train import Schedule, evaluation_sets, held_out, learning_rate, predict_all
    from jaxcls.perception import pointnet

    config = _tiny_config(workspace, out_dir=str(workspace / "cosine"), epochs=2, schedule=Schedule.cosine,
                          final_lr=0.1)
    run = train(config, show_progress=False)
    history = _history(run)
    rate = learning_rate(config, config.steps_per_epoch)  # the rate of each epoch's last step is logged
    assert [h["learning_rate"] for h in history] == pytest.approx([float(rate(5 * e - 1)) for e in (1, 2)], rel=1e-6)
    assert 3e-4 > history[0]["learning_rate"] > history[1]["learning_rate"] > 3e-4 * 0.1
    # The held-out NLL is scikit-learn's log loss of the same probabilities.
    classifier = pointnet.load_classifier(run / "pointnet.msgpack")
    object_set = builtin_object_set(train_per_class=1, test_per_class=1, surface_samples=2500)
    test = clouds.load_clouds(object_set, "test", config.data, config.objects, config.seed, False, config.perception)
    evals = evaluation_sets(test, config)
    accuracy, nll = held_out(classifier, evals, config.eval_batch)
    points, mask, label, _ = evals["view"]
    probs = predict_all(classifier, points, mask, config.eval_batch, pointnet.classify)
    assert nll["view"] == pytest.approx(log_loss(label, probs, labels=np.arange(probs.shape[1])), rel=1e-4)
    assert accuracy["view"] == pytest.approx(np.mean(probs.argmax(-1) == label))
    assert history[-1]["test_accuracy"]["view"] == pytest.approx(accuracy["view"], abs=0.15)  # float16 export
    with pytest.raises(ValueError, match="epochs"):
        train(dataclasses.replace(config, epochs=3), show_progress=False)

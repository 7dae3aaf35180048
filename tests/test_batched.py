"""Episodes batched over scenes and runs (``episode.batched``): one switched program runs every policy row with
GR on or off and gives the records of each row's own program; switching rows compiles nothing; the batch
sharded over 4 (CPU-simulated) devices gives the records of one device."""

from __future__ import annotations

import dataclasses
import json
import os
import pickle
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

from jaxcls.episode import active, batched, protocol, scoring, setup
from jaxcls.experiments.table1 import runner
from jaxcls.geometry import CameraConfig
from jaxcls.perception.settings import PerceptionConfig, ShapeConfig
from jaxcls.perception.tracking import TrackingConfig
from jaxcls.world.scenes import SceneConfig
from jaxcls.world.setup import WorldConfig, make_world

ROOT = Path(__file__).resolve().parents[1]
WORLD = WorldConfig(camera=CameraConfig.kinect_v1(0.25), scene=SceneConfig(num_objects=3), backend="mujoco",
                    viewpoints=dataclasses.replace(WorldConfig().viewpoints, count=30))
MOVES = 3
RUNS = 2
# Frames fused at the poses given: a tracked pose differs between two compiled programs in its last float32
# digits, which moves the fused surface chaotically downstream (test_episode.py says the same of vmap).
SETTINGS = setup.ActiveConfig(
    episode=active.EpisodeConfig(moves=MOVES),
    perception=PerceptionConfig(shapes=ShapeConfig(surface_points=4096, points_per_segment=128),
                                tracking=TrackingConfig(mode="reported")))
ROWS = ("random", "vis_occl_hist_gr", "single_gr")


def scenes(count: int = 2):
    """``count`` scenes' frames from every viewpoint: depth [S, V, H, W], T_wc [S, V, 4, 4], and the worlds."""
    worlds = [make_world(WORLD, seed=s) for s in range(1, count + 1)]
    measured = [w.measure(jax.random.PRNGKey(s), np.arange(len(w.viewpoints))) for s, w in enumerate(worlds)]
    return (np.stack([m[0] for m in measured]), np.stack([m[1] for m in measured]).astype(np.float32), worlds)


def records(traces, truths, scene, start, moves=MOVES):
    """Each episode's path and target labels (prior and refined after each of its first ``moves`` moves)."""
    out = []
    for e in range(len(scene)):
        r = protocol.episode_record(jax.tree.map(lambda x, e=e: x[e, :moves], traces), truths[scene[e]],
                                    start=int(start[e]))
        out.append({k: r[k] for k in ("path", "prior", "refined")})
    return out


@pytest.fixture(scope="module")
def data():
    return scenes()


def test_one_program_runs_every_row_as_its_own_program_does(data, tmp_path, host_arrays):
    depth, T_wc, worlds = data
    world = worlds[0]
    truths = [scoring.Truth.from_scene(w.scene, w.object_set) for w in worlds]
    base = setup.make_episode(SETTINGS, world.object_set, world.intrinsics, world.table_height)
    policies = tuple(dict.fromkeys(runner.program_row(protocol.ROWS[r]).policy for r in ROWS))
    switched = base.switched(policies)
    scene = np.repeat(np.arange(len(worlds)), RUNS)
    start = np.concatenate([protocol.start_views(0, s, RUNS, T_wc.shape[1]) for s in range(len(worlds))])
    keys = np.concatenate([np.asarray(protocol.run_keys(0, s, RUNS)) for s in range(len(worlds))])
    program = batched._program(batched.mesh(), False)
    compiled, own_records = [], {}
    for name in ROWS:
        row = protocol.ROWS[name]
        # PointNetSingle: the first move of the program's VisOcclHist with the same GR (Table 1's runner).
        program_row = runner.program_row(row)
        moves = 1 if row.kind is protocol.Kind.SINGLE else MOVES
        chosen = switched.choose(program_row.policy, program_row.refinement)
        together = records(batched.rollouts(chosen, depth, T_wc, scene, start, keys), truths, scene, start, moves)
        compiled.append(program._cache_size())
        own = row.episode(SETTINGS, MOVES, base.spec.classifier, world.object_set, world.intrinsics,
                          world.table_height)
        alone = []
        for s in range(len(worlds)):
            mine = scene == s
            traces = jax.device_get(protocol.rollouts(own, depth[s], T_wc[s], start[mine], keys[mine]))
            alone += records(traces, truths, scene[mine], start[mine], moves)
        assert together == alone, name
        own_records[name] = alone
        assert all(len(set(r["path"])) == moves for r in together)
    assert compiled == [1] * len(ROWS), "switching the row compiled the batch again"
    # Table 1's last, shorter chunk and call: one scene's frames padded to the chunk's two scenes, one episode
    # padded to the call's four (copies, dropped): the same program, compiled nothing, and that episode's records.
    padded = [batched.replicate(x[:1], batched.mesh(), rows=len(worlds)) for x in (depth, T_wc)]
    np.testing.assert_array_equal(np.asarray(padded[0][1]), depth[0])
    one = batched.fetch(batched.dispatch(chosen, *padded, scene[:1], start[:1], keys[:1], size=len(scene)), 1)
    assert program._cache_size() == 1
    assert records(one, truths, scene[:1], start[:1], moves) == together[:1]
    # Table 1's runner on four CPU-simulated devices (the frames split by scene, a resumed scene's call padded;
    # the scale configs' Pallas settings): the records of the row's own program on one device, each episode once,
    # one compiled program.
    four = four_devices_run_table1(tmp_path, host_arrays)
    assert four["devices"] == 4 and four["programs"] == 1
    runs = np.tile(np.arange(RUNS), len(worlds))
    want = {(int(s), int(r)): own for s, r, own in zip(scene, runs, own_records["vis_occl_hist_gr"], strict=True)}
    assert sorted((r["scene"], r["run"]) for r in four["records"]) == sorted(k for k in want if k != (1, 0))
    for r in four["records"]:
        assert {k: r[k] for k in ("path", "prior", "refined")} == want[r["scene"], r["run"]]
    # A policy outside the program, or choosing on an unswitched episode, is refused by name.
    with pytest.raises(ValueError, match="continuous"):
        switched.choose("continuous", True)
    with pytest.raises(ValueError, match="switched"):
        base.choose("random", True)


_SHARDED = """
import dataclasses, json, pickle, sys
from pathlib import Path
import jax
from tqdm.auto import tqdm
sys.path.insert(0, {tests!r})
import test_batched as t
from jaxcls import compile_cache, io
from jaxcls.episode import batched
from jaxcls.experiments.table1 import runner
from jaxcls.experiments.table1.config import Table1Config
from jaxcls.experiments.table1.data import Chunk
from jaxcls.perception import pointnet, tsdf
from jaxcls.world.dataset import DatasetConfig

# The host arrays (the ICP targets' lookups, a pure function of their key) the test's own episodes used, handed out
# as built; any other is built here.
given = pickle.loads(Path({host!r}).read_bytes())
compile_cache.cached_arrays = lambda kind, key, build: given[kind, key] if (kind, key) in given else build()
depth, T_wc, worlds = t.scenes()
# The scale configs' Pallas kernels, which off a GPU are the XLA programs: the records stay the reference's.
volume = dataclasses.replace(t.SETTINGS.perception.volume, kernel=tsdf.FusionKernel.pallas)
perception = dataclasses.replace(t.SETTINGS.perception, classification_pooling=pointnet.PoolingKernel.pallas,
                                 volume=volume)
config = Table1Config(out_dir={out!r}, runs=t.RUNS, moves=t.MOVES, rows=("vis_occl_hist_gr",), scene_chunk=4,
                      classifiers={{"shipped": ""}}, perception=perception)


class Frames:  # the scenes' frames, handed out as Table 1's scene set does
    def prepare_renderer(self):  # (they are made already)
        pass

    def loads_beside_renders(self):  # (nothing renders)
        return True

    def chunk(self, indices):
        i = list(indices)
        return Chunk(scenes=[worlds[k].scene for k in i], depth=depth[i], T_wc=T_wc[i],
                     intrinsics=worlds[0].intrinsics)


# Table 1's runner on four devices: a scene a device (two devices hold padding), the frames split by scene;
# scene 1's run 0 stored before (a resumed run), so it is not run again, and its call padded.
store = Path({out!r}) / "episodes.jsonl"
io.append_jsonl(store, [{{"classifier": "shipped", "row": "vis_occl_hist_gr", "scene": 1, "run": 0}}])
todo = [("shipped", "vis_occl_hist_gr", s, r) for s in range(len(worlds)) for r in range(t.RUNS) if (s, r) != (1, 0)]
with tqdm(disable=True) as bar:
    runner.run_batched(config, Frames(), DatasetConfig(), {{"shipped": pointnet.load_classifier()}},
                       worlds[0].object_set, todo, store, bar)
written = io.read_jsonl(store)[1:]
print(json.dumps({{"devices": len(jax.devices()), "programs": batched._program(batched.mesh(), True)._cache_size(),
                  "records": [{{k: r[k] for k in ("scene", "run", "path", "prior", "refined")}} for r in written]}}))
"""


def four_devices_run_table1(tmp_path: Path, host_arrays: dict) -> dict:
    """Table 1's runner over ``scenes()`` on four CPU-simulated devices (``_SHARDED``), handed ``host_arrays``
    (conftest's fixture: those of the test's own episodes): its output."""
    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=4", "JAX_PLATFORMS": "cpu",
           "JAXCLS_CACHE_DIR": "off"}
    host = tmp_path / "host_arrays.pickle"
    host.write_bytes(pickle.dumps(dict(host_arrays)))
    code = _SHARDED.format(tests=str(ROOT / "tests"), out=str(tmp_path), host=str(host))
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=ROOT)
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_bad_batches_are_refused():
    episode = None  # the checks come before anything is traced
    depth, T_wc = np.zeros((2, 5, 4, 4), np.float32), np.tile(np.eye(4, dtype=np.float32), (2, 5, 1, 1))
    keys = np.zeros((2, 2), np.uint32)
    with pytest.raises(ValueError, match=r"scenes must lie in 0\.\.1"):
        batched.rollouts(episode, depth, T_wc, np.array([0, 2]), np.array([0, 1]), keys)
    with pytest.raises(ValueError, match="start views"):
        batched.rollouts(episode, depth, T_wc, np.array([0, 1]), np.array([0, 5]), keys)
    with pytest.raises(ValueError, match=r"T_wc \[S, V, 4, 4\]"):
        batched.rollouts(episode, depth, T_wc[:1], np.array([0, 1]), np.array([0, 1]), keys)
    with pytest.raises(ValueError, match="one entry per episode"):
        batched.rollouts(episode, depth, T_wc, np.array([0, 1]), np.array([0]), keys)


def test_episodes_that_render_as_they_move_give_the_records_of_frames_rendered_before():
    """``batched.rendered``: each move's frames rendered inside the episodes' program (MJX's ray caster here, a
    renderer's ``depth_fn``; Warp's batch renderer on a GPU) give the traces of ``rollouts`` over the same
    renderer's frames of every viewpoint, rendered beforehand."""
    config = dataclasses.replace(WORLD, camera=CameraConfig.kinect_v1(0.125), backend="mjx",
                                 viewpoints=dataclasses.replace(WORLD.viewpoints, count=12))
    world = make_world(config, seed=1)
    renderer = world.renderer
    T_true = np.asarray(world.viewpoints, np.float32)
    depth = np.asarray(renderer.render(T_true).depth)  # [V, H, W] before the episodes
    episode = setup.make_episode(SETTINGS, world.object_set, world.intrinsics, world.table_height)
    start = np.array([0, 7], np.int32)
    keys = np.asarray(jax.vmap(jax.random.PRNGKey)(np.arange(2)))
    before = batched.rollouts(episode, depth[None], T_true[None], np.zeros(2, np.int32), start, keys,
                              batched.mesh(jax.local_devices()[:1]))
    render = renderer.depth_fn(2)
    live = jax.device_get(batched.rendered(episode, lambda T, key: render(T), T_true, T_true, start, keys))
    assert np.array_equal(live.view, before.view) and len(set(live.view[0].tolist())) > 1
    assert np.array_equal(live.refinement.refined, before.refinement.refined)
    assert np.array_equal(live.points, before.points)
    with pytest.raises(ValueError, match=r"T_true and T_wc must both be \[V, 4, 4\]"):
        batched.rendered(episode, lambda T, key: render(T), T_true[:3], T_true, start, keys)

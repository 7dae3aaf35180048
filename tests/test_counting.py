"""Counting objects in Table 1's episodes (issue 35): the comparison of a run with N given and one with N
estimated on hand-made records (count shares by hand, a phantom's cost by hand, identical runs differ by
exactly 0, the pairing, two run folders read and refused where they differ in more than N), and an episode
with N estimated and empty segment slots, whose slots stay NaN-free and are ignored."""

from __future__ import annotations

import dataclasses
import importlib.util
import json
from pathlib import Path

import jax
import numpy as np
import pytest

from jaxcls import cli, io
from jaxcls.config import load_config, save_config
from jaxcls.episode import active, protocol, scoring, setup
from jaxcls.experiments import counting
from jaxcls.experiments.table1.config import Table1Config
from jaxcls.geometry import CameraConfig
from jaxcls.perception.settings import ObjectCount, PerceptionConfig, ShapeConfig
from jaxcls.perception.tracking import TrackingConfig, TrackingMode
from jaxcls.world.scenes import SceneConfig
from jaxcls.world.setup import WorldConfig, make_world


def _record(scene: int, run: int, segments: list[int], objects: int = 5, row: str = "random_gr",
            refined: list[list[int]] | None = None, true: list[int] | None = None,
            phantom: list[list[int]] | None = None) -> dict:
    """A hand-made Table 1 record (``protocol.episode_records``' keys that the comparison reads)."""
    T = len(segments)
    true = true if true is not None else [0, 1]
    refined = refined if refined is not None else [list(true)] * T
    return {"classifier": "shipped", "row": row, "scene": scene, "run": run, "true": true, "prior": refined,
            "refined": refined, "phantom": phantom if phantom is not None else [[] for _ in range(T)],
            "segments": segments, "objects": objects}


# Two scenes x two runs; the last episode made 3 moves of 4 (it stopped: its later counts are its last).
COUNTS = [_record(0, 0, [4, 5, 5, 5]), _record(0, 1, [5, 5, 6, 5]),
          _record(1, 0, [3, 4, 4, 4], objects=4), _record(1, 1, [4, 4, 4], objects=4)]


def test_count_shares_and_errors_by_hand():
    np.testing.assert_array_equal(counting.count_errors(COUNTS, 1), [-1, 0, -1, 0])
    np.testing.assert_array_equal(counting.count_errors(COUNTS, 4), [0, 0, 0, 0])  # past the last: its last
    first = counting.count_summary(COUNTS, 1, resamples=200)
    assert first["episodes"] == 0.5 and first["scenes"] == 0.0  # no scene right in both runs
    assert first["abs"] == 0.5 and first["mean"] == -0.5 and first["spread"] == {-1: 2, 0: 2}
    assert first["low"] <= 0.5 <= first["high"] and first["n"] == 4 and first["scene_count"] == 2
    third = counting.count_summary(COUNTS, 3, resamples=200)
    assert third["episodes"] == 0.75 and third["scenes"] == 0.5  # scene 1 right in both runs, scene 0 in one
    assert third["abs"] == 0.25 and third["mean"] == 0.25
    # Resampling scenes: scene 0 alone 1/2 right, scene 1 alone all right.
    assert third["low"] == pytest.approx(0.5) and third["high"] == pytest.approx(1.0)
    last = counting.count_summary(COUNTS, 4, resamples=200)
    assert (last["episodes"], last["low"], last["high"], last["scenes"], last["abs"]) == (1.0, 1.0, 1.0, 1.0, 0.0)


def _random_records(seed: int, scenes: int = 4, runs: int = 3, moves: int = 3, classes: int = 4) -> list[dict]:
    rng = np.random.default_rng(seed)
    out = []
    for s in range(scenes):
        true = rng.integers(0, classes, 5).tolist()
        for r in range(runs):
            refined = [rng.integers(-1, classes, 5).tolist() for _ in range(moves)]
            phantom = [rng.integers(0, classes, rng.integers(0, 3)).tolist() for _ in range(moves)]
            out.append(_record(s, r, [5 + len(p) for p in phantom], refined=refined, true=true, phantom=phantom))
    return out


def test_identical_runs_differ_by_exactly_zero():
    records = _random_records(0)
    f = counting.f1_comparison(records, records, 4, resamples=200)
    assert f["difference_phantoms"] == (0.0, 0.0, 0.0) and f["difference_plain"] == (0.0, 0.0, 0.0)
    assert f["given"] == f["estimated"] and f["given_phantoms"] == f["estimated_phantoms"]
    # The headline counts phantoms in the estimated run only: these records have some, so it is negative.
    assert f["estimated_phantoms"] < f["given"] and f["difference"][0] == pytest.approx(f["estimated_phantoms"]
                                                                                         - f["given"])
    count_rows, f1_rows = counting.episode_tables(records, records, 4, resamples=200)
    assert len(f1_rows) == 1 and f1_rows[0][-2:] == ("+0.000 [+0.000, +0.000]",) * 2
    assert len(count_rows) == 2 * 2  # (given, estimated) x moves 1 and 3 (T = 3: move 10 reads the last, once)


def test_a_phantom_costs_what_it_costs_by_hand():
    """Two scenes, both objects right in both runs; with N estimated one phantom (class 1) in scene 0. Pooled:
    class 1 has 2 of 3 detections right (precision 2/3, recall 1, F1 0.8), class 0 F1 1: macro 0.9, so the
    difference is -0.1; scene 0 alone -1/6 (F1 of class 1: 2 * 0.5 / 1.5), scene 1 alone 0: the interval."""
    given = [_record(0, 0, [2], objects=2), _record(1, 0, [2], objects=2)]
    estimated = [_record(0, 0, [3], objects=2, phantom=[[1]]), _record(1, 0, [2], objects=2)]
    f = counting.f1_comparison(given, estimated, 2, resamples=500)
    estimate, low, high = f["difference"]
    assert estimate == pytest.approx(-0.1) and low == pytest.approx(-1 / 6) and high == pytest.approx(0.0)
    assert f["difference_plain"] == (0.0, 0.0, 0.0) and f["estimated_phantoms"] == pytest.approx(0.9)
    assert counting.count_summary(estimated, 1, 200)["episodes"] == 0.5


def test_runs_are_paired_by_scene_and_run():
    known = [_record(0, 0, [5]), _record(1, 1, [5]), _record(0, 1, [5]), _record(2, 0, [5]),
             _record(0, 0, [5], row="single_gr"), _record(0, 0, [4])]  # (a repeat: the first kept)
    estimated = [_record(0, 1, [6]), _record(0, 0, [4]), _record(1, 1, [5]), _record(3, 0, [5])]
    pairs = counting.paired_runs(known, estimated)
    assert list(pairs) == [("shipped", "random_gr")]  # single_gr: only in the known run
    k, e = pairs["shipped", "random_gr"]
    assert [(r["scene"], r["run"]) for r in k] == [(0, 0), (0, 1), (1, 1)] == [(r["scene"], r["run"]) for r in e]
    assert [r["segments"] for r in k] == [[5], [5], [5]] and [r["segments"] for r in e] == [[4], [6], [5]]


def _run_folder(folder: Path, records: list[dict], **settings) -> Path:
    shapes = ShapeConfig(**settings)
    config = Table1Config(out_dir=str(folder), rows=("random_gr",), runs=3, moves=3, classifiers={"shipped": ""},
                          perception=dataclasses.replace(setup.episode_perception(), shapes=shapes))
    save_config(config, folder / "config.yaml")
    io.append_jsonl(folder / "episodes.jsonl", records)
    return folder


def test_two_run_folders_compared_and_other_settings_refused(tmp_path, capsys):
    records = _random_records(1, classes=8)
    known = _run_folder(tmp_path / "known", records, num_segments=5)
    estimated = _run_folder(tmp_path / "estimated", records, num_segments=8, num_objects=ObjectCount.estimated)
    count_rows, f1_rows, facts = counting.compare_runs(known, estimated, resamples=200)
    assert len(count_rows) == 2 * 2  # (given, estimated) x moves 1 and 3 (T = 3: 10 reads the last, once)
    assert facts["slots"] == 8 and facts["given_slots"] == 5 and len(f1_rows) == 1 and f1_rows[0][1] == "RandomGR"
    assert f1_rows[0][-2:] == ("+0.000 [+0.000, +0.000]",) * 2
    with pytest.raises(ValueError, match="expected known"):
        counting.compare_runs(estimated, known)
    other = _run_folder(tmp_path / "other", records, num_segments=8, num_objects=ObjectCount.estimated,
                        points_per_segment=512)
    with pytest.raises(ValueError, match=r"perception\.shapes\.points_per_segment"):
        counting.compare_runs(known, other)
    # The command line: the section with both tables (the classes from the dataset's object set).
    spec = importlib.util.spec_from_file_location("counting_script", Path(__file__).parents[1] / "experiments"
                                                  / "counting.py")
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    out = tmp_path / "results.md"
    script.main(["--episodes", str(known), str(estimated), "--moves", "1", "3", "--resamples", "200",
                 "--out", str(out)])
    text = out.read_text()
    assert "N given against N estimated" in text and "| shipped | RandomGR | estimated | 3 | 12 |" in text
    assert text.strip() == capsys.readouterr().out.strip()  # printed and appended


@pytest.mark.parametrize("dataset", ["synthetic", "real_like"])
def test_the_shipped_estimated_config_is_the_given_one_but_for_n(dataset):
    given, estimated = (load_config(Table1Config, name)
                        for name in (f"table1_{dataset}", f"table1_{dataset}_estimated"))
    assert given.dataset == estimated.dataset == dataset
    assert counting.run_settings_differ(given, estimated) == [] and given.rows == estimated.rows
    assert estimated.perception.shapes.num_objects == ObjectCount.estimated
    assert estimated.perception.shapes.num_segments == 8 and given.classifiers == estimated.classifiers
    assert given.out_dir != estimated.out_dir  # (a store holds one config's episodes)


def _cylinder(cx: float, cy: float, radius: float, height: float, spacing: float = 0.006
              ) -> tuple[np.ndarray, np.ndarray]:
    """An upright closed cylinder on the table (z = 0), m: side wall (outward normals) and top (normals up),
    points about ``spacing`` apart: (points [M, 3] f32, normals [M, 3] f32)."""
    a = np.linspace(0, 2 * np.pi, int(2 * np.pi * radius / spacing), endpoint=False)
    z = np.arange(0.015, height, spacing)
    u = np.repeat(np.c_[np.cos(a), np.sin(a)], len(z), axis=0)
    side = np.c_[cx + radius * u[:, 0], cy + radius * u[:, 1], np.tile(z, len(a))]
    g = np.arange(-radius, radius + 1e-9, spacing)
    gx, gy = (v.ravel() for v in np.meshgrid(g, g))
    inside = gx**2 + gy**2 <= radius**2
    top = np.c_[cx + gx[inside], cy + gy[inside], np.full(inside.sum(), height)]
    normals = np.r_[np.c_[u, np.zeros(len(u))], np.tile([0.0, 0.0, 1.0], (len(top), 1))]
    return np.r_[side, top].astype(np.float32), normals.astype(np.float32)


def test_extra_segments_explained_against_their_objects():
    """``explain_surface`` on a hand-made surface of three cylinders apart: two owned by object 0 (the smaller
    is its ``second`` segment), one by none (a ``ghost``); areas, heights and persistences as built (apart on
    the table: >= 1, the highest basin inf); object 0 found, object 1 (no points) unseen; ``explain_rows``
    counts the two extras and the missed object."""
    from jaxcls.geometry import Intrinsics
    from jaxcls.perception.settings import Spec

    spec = Spec.create(PerceptionConfig(shapes=ShapeConfig(num_segments=6, num_objects=ObjectCount.estimated)),
                       Intrinsics.kinect_v1(0.5))
    parts = [((-0.12, 0.0, 0.035, 0.06), 0), ((0.12, 0.0, 0.025, 0.09), 0), ((0.0, 0.15, 0.03, 0.05), -1)]
    clouds = [_cylinder(*shape) for shape, _ in parts]
    points, normals = np.concatenate([c[0] for c in clouds]), np.concatenate([c[1] for c in clouds])
    owners = np.concatenate([np.full(len(c[0]), o) for c, (_, o) in zip(clouds, parts, strict=True)])
    surface = counting.explain_surface(spec, points, normals, np.ones(len(points), bool), owners, objects=2)
    described = surface["segments"]
    assert [(o["fate"], o["points"] > 0) for o in surface["objects"]] == [("found", True), ("unseen", False)]
    by_kind = {d["kind"]: d for d in described}
    assert sorted(by_kind) == ["ghost", "object", "second"], described
    for (cx, cy, radius, height), _ in parts:
        d = min(described, key=lambda d: np.hypot(d["centre"][0] - cx, d["centre"][1] - cy))
        assert abs(d["area"] / (np.pi * radius**2) - 1) < 0.3 and abs(d["height"] - height) < 0.005, d
        assert d["persistence"] >= 1.0 and d["basins"] >= 1 and d["purity"] in (0.0, 1.0)
    assert by_kind["second"]["object"] == by_kind["object"]["object"] == 0 and by_kind["ghost"]["object"] == -1
    assert by_kind["second"]["points"] < by_kind["object"]["points"] and by_kind["ghost"]["unowned"] == 1.0
    named = [{**d, "name": "box_test_000" if d["object"] == 0 else ""} for d in described]
    rows = counting.explain_rows([{"move": 3, "segments": named,
                                   "fates": [{**o, "name": f"can_test_00{o['object']}"} for o in surface["objects"]]}])
    assert sorted((r[1], r[2], r[3], r[4]) for r in rows) == [("ghost", "apart", "none", 1),
                                                              ("missed: unseen", "", "can", 1),
                                                              ("second", "apart", "box", 1)]


def test_clutter_is_an_object_to_count_and_no_phantom():
    """A real-like scene's records count every object on the table, the 2 clutter objects with the 3 targets:
    ``objects`` 5, ``true`` the targets only; a live segment on a clutter object is matched (no phantom), one on
    nothing is a phantom; the count errors read against 5 (one clutter object missed, then one phantom)."""
    from types import SimpleNamespace

    from jaxcls.perception.tracking import Status

    K, N, T = 5, 8, 2
    at = np.c_[np.arange(K) * 0.15, np.zeros(K), np.full(K, 0.05)]  # objects 15 cm apart; 3, 4 clutter
    truth = scoring.Truth(centroid=at, label=np.arange(K), target=np.arange(K) < 3, surface=(), names=())
    centroid, valid = np.zeros((1, T, N, 3)), np.zeros((1, T, N), bool)
    centroid[0, 0, :4], valid[0, 0, :4] = at[:4], True  # move 1: clutter object 4 not found
    centroid[0, 1, :5], valid[0, 1, :6] = at, True  # move 2: all 5, and a segment where no object stands
    centroid[0, 1, 5] = (0.3, 0.4, 0.05)
    refined = np.broadcast_to(np.r_[np.arange(5), 6, 6, 6], (1, T, N)).copy()
    trace = SimpleNamespace(refinement=SimpleNamespace(prior=refined, refined=refined, valid=valid),
                            centroid=centroid, done=np.zeros((1, T), bool), view=np.array([[3, 7]]),
                            tracking=np.full((1, T), int(Status.ACCEPTED)), hand_eye=np.broadcast_to(np.eye(4),
                                                                                                      (1, T, 4, 4)))
    record = protocol.episode_records(trace, [truth], [{"scene": 0, "run": 0}])[0]
    assert record["objects"] == 5 and record["true"] == [0, 1, 2] and record["segments"] == [4, 6]
    assert record["refined"] == [[0, 1, 2], [0, 1, 2]] and record["phantom"] == [[], [6]]
    assert counting.count_errors([record], 1).tolist() == [-1] and counting.count_errors([record], 2).tolist() == [1]


def test_explain_rows_name_clutter():
    """``explain_rows`` on a real-like scene's descriptions: a clutter object's second segment and its missed
    fate name the class ``(clutter)``; a target merged into a clutter object's segment reads ``missed: merged
    into clutter``, a clutter object merged into a target's ``missed: merged``; records without ``target`` (the
    synthetic runs') read as before."""
    second = {"kind": "second", "persistence": 0.3, "area": 2e-3, "height": 0.05}
    explained = [{"move": 3,
                  "segments": [{**second, "name": "bowl_test_000", "target": False},
                               {**second, "name": "box_test_001", "target": True}, {**second, "name": "mug_test_002"}],
                  "fates": [{"fate": "merged", "name": "can_test_000", "target": True, "into_target": False},
                            {"fate": "merged", "name": "jug_test_001", "target": False, "into_target": True},
                            {"fate": "dropped", "name": "lamp_test_002", "target": False},
                            {"fate": "merged", "name": "drill_test_003"}]}]
    rows = {(r[1], r[3]): r[4] for r in counting.explain_rows(explained)}
    assert rows == {("second", "bowl (clutter)"): 1, ("second", "box"): 1, ("second", "mug"): 1,
                    ("missed: merged into clutter", "can"): 1, ("missed: merged", "jug (clutter)"): 1,
                    ("missed: dropped", "lamp (clutter)"): 1, ("missed: merged", "drill"): 1}


def test_the_real_like_kind_is_measured_through_its_sensor():
    """``fused_real_like``: the ``real_like`` config's scene (5 objects of which 2 clutter), its frames through
    the sensor model (depth unlike the ideal render) and fused at the poses reported (the hand-eye error: unlike
    the poses rendered); the same seed, the same frames."""
    seen = []

    def observe(spec, state, depth, T_wc):
        seen.append((np.asarray(depth), np.asarray(T_wc)))
        return state

    world, _, _, states = counting.fused_real_like("real_like", 3, 0.25, PerceptionConfig(), observe, (1, 2))
    assert sorted(states) == [1, 2] and len(seen) == 2
    assert len(world.scene.objects) == 5 and sum(not o.target for o in world.scene.objects) == 2
    views = list(counting.segmentation.VIEWS[:2])
    ideal, rendered = np.asarray(world.render(views).depth), world.poses(views)
    for (depth, T_wc), d, T in zip(seen, ideal, rendered, strict=True):
        assert not np.allclose(T_wc, T, atol=1e-5) and np.abs(T_wc - T).max() < 0.05
        assert not np.allclose(depth, d, atol=1e-4)
    again = []
    counting.fused_real_like("real_like", 3, 0.25, PerceptionConfig(), lambda sp, st, d, T: again.append(d) or st, (1,))
    np.testing.assert_array_equal(again[0], seen[0][0])


def test_walk_rows_by_hand():
    """``walk_rows``: a variant's walks right, over and under after each move, objects found and their points
    in their segment, counted by hand."""
    records = [{"variant": v, "move": m, "objects": 5, "count": c, "scene": 0, "run": r, "seen": 5, "found": f,
                "whole": w}
               for v, m, r, c, f, w in (("off", 3, 0, 6, 5, 4.5), ("off", 3, 1, 5, 5, 4.5), ("off", 10, 0, 4, 4, 4.0),
                                        ("off", 10, 1, 5, 5, 5.0), ("rule", 3, 0, 5, 5, 5.0), ("rule", 3, 1, 5, 5, 5.0),
                                        ("rule", 10, 0, 5, 5, 5.0), ("rule", 10, 1, 5, 5, 5.0))]
    assert counting.walk_rows(records) == [("off", 3, 2, "0.500", 1, 0, "1.000", "0.900"),
                                           ("off", 10, 2, "0.500", 0, 1, "0.900", "1.000"),
                                           ("rule", 3, 2, "1.000", 0, 0, "1.000", "1.000"),
                                           ("rule", 10, 2, "1.000", 0, 0, "1.000", "1.000")]


def test_object_coverage_by_hand():
    """``object_coverage``: objects seen, found (their points mostly in a segment mostly theirs) and the share
    of a found object's points in its segment."""
    MP = counting.MISSED_POINTS
    owners = np.r_[np.zeros(2 * MP), np.ones(2 * MP), np.full(MP // 2, 2), np.full(10, -1)].astype(np.int64)
    labels = np.r_[np.zeros(MP + MP // 2), np.full(MP // 2, -1),  # object 0: 3/4 in segment 0, the rest dropped
                   np.zeros(MP // 4), np.full(2 * MP - MP // 4, 1),  # object 1: mostly segment 1
                   np.full(MP // 2, 1), np.full(10, 1)].astype(np.int64)  # object 2 unseen; table points in 1
    assert counting.object_coverage(labels, owners, 3) == {"seen": 2, "found": 2,
                                                           "whole": 0.75 + (2 * MP - MP // 4) / (2 * MP)}
    assert counting.object_coverage(np.full(len(owners), -1), owners, 3) == {"seen": 2, "found": 0, "whole": 0.0}


# --- An episode with N estimated: empty slots through PointNet, GR, visibility and the records -------------

CAMERA = CameraConfig.kinect_v1(0.5)
WORLD = WorldConfig(camera=CAMERA, scene=SceneConfig(num_objects=3), backend="mujoco",
                    viewpoints=dataclasses.replace(WorldConfig().viewpoints, count=40))
SMALL = [*(f"camera.{f.name}={getattr(CAMERA, f.name)}" for f in dataclasses.fields(CAMERA)),
         "perception.shapes.surface_points=8192", "perception.shapes.points_per_segment=256", "scene.num_objects=3",
         "viewpoints.count=40", "backend=mujoco"]


def _estimated_episode(world, slots: int, policy: str = "vis_occl_hist") -> active.Episode:
    shapes = ShapeConfig(surface_points=8192, points_per_segment=256, num_segments=slots,
                         num_objects=ObjectCount.estimated)
    # Frames fused at the poses given: the slots are the subject, not tracking (half the compile, ~20 s a program).
    settings = setup.ActiveConfig(episode=active.EpisodeConfig(moves=3, policy=policy),
                                  perception=PerceptionConfig(shapes=shapes,
                                                              tracking=TrackingConfig(mode=TrackingMode.reported)))
    return setup.make_episode(settings, world.object_set, world.intrinsics, world.table_height)


# The rollouts compiled with LLVM's optimisation off (XLA's own passes as ever): the same program, its records the
# same as the default compile's (checked when this was written), in a third of the compile time on the 2-core CPU.
_ROLLOUTS = jax.jit(protocol.rollouts, compiler_options={"xla_backend_optimization_level": 0})


@pytest.fixture(scope="module")
def scene():
    world = make_world(WORLD, seed=1)
    depth, T_wc, _, _ = world.measure(jax.random.PRNGKey(0), np.arange(len(world.viewpoints)))
    return world, depth, T_wc


def test_empty_slots_stay_finite_and_are_ignored(scene):
    """Three objects in 8 slots and in 5: every float of the traces finite, an empty slot neither live, nor a
    model, nor a phantom; the records (paths, labels, counts, phantoms) the same with 3 more empty slots."""
    world, depth, T_wc = scene
    truth = scoring.Truth.from_scene(world.scene, world.object_set)
    starts, keys = np.array([5, 11, 30]), protocol.run_keys(0, 0, 3)
    records = {}
    for slots in (8, 5):
        trace = jax.device_get(_ROLLOUTS(_estimated_episode(world, slots), depth, T_wc, starts, keys))
        for path, x in jax.tree_util.tree_leaves_with_path(trace):
            x = np.asarray(x)
            assert x.dtype.kind != "f" or np.isfinite(x).all(), jax.tree_util.keystr(path)
        valid, points = np.asarray(trace.refinement.valid), np.asarray(trace.points)
        # Live: a slot with points, but one GR explains as a part of a larger segment's object (``explained``).
        assert not (valid & (points == 0)).any()
        live = valid.sum(-1)
        # Found, slots left empty; never more than 5 (else the 5-slot run must merge where the 8-slot one need not).
        assert live.max() <= 5 and (live[:, -1] >= 2).all() and (live < slots).all()
        assert (np.asarray(trace.refinement.model)[~valid] == -1).all()
        assert (np.asarray(trace.refinement.rho)[~valid] == 0).all()
        records[slots] = protocol.episode_records(trace, [truth] * 3, [{"run": r} for r in range(3)])
        for r, lv in zip(records[slots], live, strict=True):
            assert r["segments"] == lv.tolist() and r["objects"] == 3
            assert all(len(p) <= s for p, s in zip(r["phantom"], r["segments"], strict=True))
    assert json.dumps(records[8]) == json.dumps(records[5])


def test_jaxcls_run_with_n_estimated(tmp_path, capsys):
    out = tmp_path / "run"
    # Frames fused at the poses given: N estimated through the CLI is the subject, not tracking (18 -> 7 s).
    assert cli.main(["run", *SMALL, "episode.moves=2", "perception.shapes.num_objects=estimated",
                     "perception.shapes.num_segments=8", "perception.tracking.mode=reported", f"out_dir={out}"]) == 0
    printed = capsys.readouterr()
    assert "move  2" in printed.out and "phantom(s), F1 with phantoms counted" in printed.err  # (the summary)
    log = json.loads((out / "episode.json").read_text())
    assert all(1 <= len(m["segments"]) <= 8 for m in log["moves"])
    assert "num_objects: estimated" in (out / "config.yaml").read_text()


def test_n_known_ignores_the_explained_parts_rule(scene):
    """``segmentation.explained_share`` (the estimated count's rule after GR) changes nothing with N known: three
    objects in 5 known slots (K-means parts objects, parts the rule would explain), the same traces leaf for leaf
    with the rule at 0 and at 0.5."""
    world, depth, T_wc = scene
    traces = []
    for share in (0.0, 0.5):
        shapes = ShapeConfig(surface_points=8192, points_per_segment=256, num_segments=5)  # (K-means splits)
        segmentation = dataclasses.replace(PerceptionConfig().segmentation, explained_share=share)
        settings = setup.ActiveConfig(episode=active.EpisodeConfig(moves=2), perception=PerceptionConfig(
            shapes=shapes, segmentation=segmentation, tracking=TrackingConfig(mode=TrackingMode.reported)))
        episode = setup.make_episode(settings, world.object_set, world.intrinsics, world.table_height)
        traces.append(jax.device_get(_ROLLOUTS(episode, depth, T_wc, np.array([5]), protocol.run_keys(0, 0, 1))))
    for a, b in zip(jax.tree.leaves(traces[0]), jax.tree.leaves(traces[1]), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))

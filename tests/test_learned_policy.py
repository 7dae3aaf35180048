"""The learned view policy (``planning.learned``, ``nbv.Learned``): a drop-in policy of the episode under vmap and
in the switched program; weights whose network passes the paper's utility through choose what VisOcclHist
chooses, in the episode and in PPO's rollouts; a weights file of other shapes, another layout or another candidate
count is refused by name; a weight soup (``experiments/policy_soup.py``) is its members' mean."""

from __future__ import annotations

import dataclasses
import hashlib
import importlib.util
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxcls.config import load_config, resolve_config
from jaxcls.episode import active, batched, protocol, setup
from jaxcls.experiments.policy.config import PolicyConfig
from jaxcls.geometry import CameraConfig
from jaxcls.perception.settings import PerceptionConfig, ShapeConfig
from jaxcls.perception.tracking import TrackingConfig
from jaxcls.planning import learned, nbv
from jaxcls.world.scenes import SceneConfig
from jaxcls.world.setup import WorldConfig, make_world

WORLD = WorldConfig(camera=CameraConfig.kinect_v1(0.25), scene=SceneConfig(num_objects=3), backend="mujoco",
                    viewpoints=dataclasses.replace(WorldConfig().viewpoints, count=30))
SETTINGS = setup.ActiveConfig(
    episode=active.EpisodeConfig(moves=3),
    perception=PerceptionConfig(shapes=ShapeConfig(surface_points=4096, points_per_segment=128),
                                tracking=TrackingConfig(mode="reported")))


def utility_passed_through(hidden: int = 8) -> dict:
    """Weights whose score is the candidate's VisOcclHist utility, exactly: every kernel 0 but the path that
    carries that feature (>= 0, so the ReLUs pass it) to the MLP's score; the linear term 0."""
    weights = jax.tree.map(np.zeros_like, jax.device_get(learned.init(jax.random.key(0), hidden)))
    p = weights["params"]
    p["candidate_0"]["kernel"][2 * hidden + learned.VIS_OCCL_HIST, 0] = 1.0
    p["candidate_1"]["kernel"][0, 0] = 1.0
    p["score"]["kernel"][0, 0] = 1.0
    return weights


def test_features_are_finite_and_carry_the_hand_made_utilities():
    from jaxcls.perception import tsdf

    world = make_world(WORLD, seed=1)
    views = nbv.Views.start(world.viewpoints, 0)
    corners = np.tile(np.array([[[x, y, z] for x in (-0.03, 0.03) for y in (-0.03, 0.03) for z in (0, 0.08)]],
                               np.float32), (3, 1, 1))
    poses = np.tile(np.eye(4, dtype=np.float32), (3, 1, 1))
    poses[:, :3, 3] = [[0.0, 0.0, world.table_height], [0.1, 0.05, world.table_height], [0, 0, 0]]
    belief = nbv.Belief(corners=jnp.asarray(corners), poses=jnp.asarray(poses), live=jnp.array([True, True, False]),
                        uncertainty=jnp.array([0.2, 0.9, 0.5]),
                        volume=tsdf.create_volume(np.array([0.0, 0.0, world.table_height]), 0.4, 32))
    config = nbv.NBVConfig()
    index, ok = nbv.candidates(views, config)
    x = learned.features(views, belief, index, ok, world.intrinsics, config)
    assert x.pair.shape == (len(index), 3, learned.Layout.v2.pair_features)
    assert x.candidate.shape == (len(index), learned.CANDIDATE_FEATURES)
    assert np.all(np.isfinite(np.asarray(x.pair))) and np.all(np.isfinite(np.asarray(x.candidate)))
    want = nbv.VisOcclHist().utilities(views, belief, index, world.intrinsics, config)
    np.testing.assert_array_equal(np.asarray(x.candidate[:, learned.VIS_OCCL_HIST]), np.asarray(want))
    want = nbv.InfoGain().utilities(views, belief, index, world.intrinsics, config)
    np.testing.assert_array_equal(np.asarray(x.candidate[:, learned.INFO_GAIN]), np.asarray(want))
    # Started from a hand-made policy, the network scores exactly its utility; "none" does not.
    for base, at in (("info_gain", learned.INFO_GAIN), ("vis_occl_hist", learned.VIS_OCCL_HIST)):
        np.testing.assert_array_equal(np.asarray(learned.apply(learned.init(jax.random.key(4), 16, base), x)),
                                      np.asarray(x.candidate[:, at]))
    assert not np.allclose(np.asarray(learned.apply(learned.init(jax.random.key(4), 16), x)),
                           np.asarray(x.candidate[:, learned.INFO_GAIN]))
    with pytest.raises(ValueError, match="volume"):
        learned.features(views, belief.replace(volume=None), index, ok, world.intrinsics, config)
    assert np.all(np.asarray(x.pair[:, 2, :]) == 0), "a dead segment carries nothing"
    nothing = learned.features(views, belief.replace(live=jnp.zeros(3, bool)), index, ok, world.intrinsics, config)
    scores = learned.apply(learned.init(jax.random.key(1), 16), nothing)
    assert np.all(np.isfinite(np.asarray(scores)))
    # Permutation-invariant over the segments, equivariant over the candidates.
    weights = learned.init(jax.random.key(2), 16)
    base = np.asarray(learned.apply(weights, x))
    turned = learned.Features(pair=x.pair[::-1, ::-1], live=x.live[::-1], candidate=x.candidate[::-1])
    np.testing.assert_allclose(np.asarray(learned.apply(weights, turned)), base[::-1], rtol=1e-5, atol=1e-6)
    batch = jax.tree.map(lambda a: jnp.stack([a, a]), x)
    np.testing.assert_allclose(np.asarray(learned.apply(weights, batch)), np.stack([base, base]), rtol=1e-6)


def test_layout_3_adds_where_a_view_sees_each_segment_from_in_its_models_frame(tmp_path):
    """Layout 3: layout 2's pair features, then the unit vector from the segment's cuboid centre to the camera in
    the aligned model's frame (analytic here; unchanged when the whole scene moves rigidly), the cuboid's size in
    dm and rho's best two; 0 for a dead segment. A fresh layout-3 network still scores InfoGain exactly, and its
    weights file says layout 3 and loads as such."""
    from jaxcls.perception import tsdf

    world = make_world(WORLD, seed=1)
    views = nbv.Views.start(world.viewpoints, 0)
    corners = np.array([[x, y, z] for x in (-0.03, 0.03) for y in (-0.02, 0.02) for z in (0, 0.08)], np.float32)
    turn = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1]], np.float32)  # (a quarter turn about z)
    poses = np.tile(np.eye(4, dtype=np.float32), (3, 1, 1))
    poses[1, :3, :3] = turn
    poses[:2, :3, 3] = [[0.0, 0.0, world.table_height], [0.1, 0.05, world.table_height]]
    belief = nbv.Belief(corners=jnp.asarray(np.tile(corners, (3, 1, 1))), poses=jnp.asarray(poses),
                        live=jnp.array([True, True, False]), uncertainty=jnp.array([0.2, 0.9, 0.5]),
                        volume=tsdf.create_volume(np.array([0.0, 0.0, world.table_height]), 0.4, 32),
                        rho=jnp.array([[0.5, 0.9, 0.1], [0.3, 0.0, 0.0], [0.7, 0.6, 0.0]]))
    config = nbv.NBVConfig()
    index, ok = nbv.candidates(views, config)
    old = learned.features(views, belief, index, ok, world.intrinsics, config)
    x = learned.features(views, belief, index, ok, world.intrinsics, config, learned.Layout.v3)
    assert x.pair.shape == (len(index), 3, learned.Layout.v3.pair_features)
    np.testing.assert_array_equal(np.asarray(x.pair[..., :4]), np.asarray(old.pair))
    np.testing.assert_array_equal(np.asarray(x.candidate), np.asarray(old.candidate))
    camera = np.asarray(views.T_wc)[np.asarray(index), :3, 3]
    centre = np.array([0.0, 0.0, 0.04])
    for n in range(2):
        local = (camera - poses[n, :3, 3]) @ poses[n, :3, :3] - centre  # R^T (p - t) - c, row by row
        np.testing.assert_allclose(np.asarray(x.pair[:, n, 4:7]), local / np.linalg.norm(local, axis=1)[:, None],
                                   atol=1e-5)
        np.testing.assert_allclose(np.asarray(x.pair[:, n, 7:10]), np.broadcast_to([0.6, 0.4, 0.8], (len(index), 3)),
                                   atol=1e-5)
    np.testing.assert_allclose(np.asarray(x.pair[:, 0, 10:]), np.broadcast_to([0.9, 0.5], (len(index), 2)))
    np.testing.assert_allclose(np.asarray(x.pair[:, 1, 10:]), np.broadcast_to([0.3, 0.0], (len(index), 2)))
    assert np.all(np.asarray(x.pair[:, 2, :]) == 0), "a dead segment carries nothing"
    # The whole scene moved rigidly (the cameras and the models' poses): where each view sees each model from is
    # the same.
    moved = np.eye(4, dtype=np.float32)
    moved[:3, :3] = np.array([[0.6, -0.8, 0], [0.8, 0.6, 0], [0, 0, 1]], np.float32)
    moved[:3, 3] = [0.3, -0.2, 0.1]
    there = learned._seen_from(jnp.asarray(moved) @ views.T_wc[index],
                               belief.replace(poses=jnp.asarray(moved) @ belief.poses))
    np.testing.assert_allclose(np.asarray(there), np.asarray(x.pair[..., 4:]), atol=1e-5)
    with pytest.raises(ValueError, match=r"layout 3 needs Belief\.rho"):
        learned.features(views, belief.replace(rho=None), index, ok, world.intrinsics, config, learned.Layout.v3)
    weights = learned.init(jax.random.key(4), 16, "info_gain", learned.Layout.v3)
    assert learned.Layout.of(weights) is learned.Layout.v3 and learned.Layout.of(learned.init(
        jax.random.key(4), 16)) is learned.Layout.v2
    np.testing.assert_array_equal(np.asarray(learned.apply(weights, x)), np.asarray(x.candidate[:, learned.INFO_GAIN]))
    np.testing.assert_array_equal(
        np.asarray(learned.scores(weights, views, belief, index, ok, world.intrinsics, config)),
        np.asarray(learned.apply(weights, x)))  # (the weights' own layout)
    path = learned.save(tmp_path / "v3.msgpack", weights, 32)
    assert json.loads(path.with_suffix(".json").read_text())["features"] == 3
    loaded, info = learned.load(path, 32)
    assert info.features == 3 and learned.Layout.of(loaded) is learned.Layout.v3


def test_the_learned_policy_runs_in_the_switched_program_and_passes_the_papers_utility_through(tmp_path):
    world = make_world(WORLD, seed=1)
    depth, T_wc, _, _ = world.measure(jax.random.PRNGKey(0), np.arange(len(world.viewpoints)))
    path = learned.save(tmp_path / "policy.msgpack", utility_passed_through(), SETTINGS.nbv.max_candidates)
    settings = dataclasses.replace(SETTINGS, nbv=dataclasses.replace(
        SETTINGS.nbv, learned=nbv.Learned(weights=str(path))))
    episode = setup.make_episode(settings, world.object_set, world.intrinsics, world.table_height)
    switched = episode.switched(("vis_occl_hist", "learned"))
    start = protocol.start_views(0, 0, 2, len(world.viewpoints))
    keys = np.asarray(protocol.run_keys(0, 0, 2))
    frames = depth[None], np.asarray(T_wc, np.float32)[None]
    scene = np.zeros(2, np.int32)
    paper = batched.rollouts(switched.choose("vis_occl_hist", True), *frames, scene, start, keys)
    ours = batched.rollouts(switched.choose("learned", True), *frames, scene, start, keys)
    np.testing.assert_array_equal(ours.view, paper.view)
    np.testing.assert_array_equal(ours.refinement.refined, paper.refinement.refined)
    assert all(len(set(p.tolist())) == 3 for p in ours.view), "a path revisits a view"
    # Other weights are another policy of the same program: valid paths, the same shapes.
    other = learned.init(jax.random.key(3), 8)
    mixed = batched.rollouts(switched.choose("learned", True).replace(policy_weights=other), *frames, scene, start,
                             keys)
    assert mixed.view.shape == paper.view.shape and all(len(set(p.tolist())) == 3 for p in mixed.view)
    reinforcement_rollouts_take_the_actors_paths(episode, world, frames, start, paper)


def reinforcement_rollouts_take_the_actors_paths(episode, world, frames, start, paper):
    """PPO's rollout (``experiments.policy.ppo``) with that actor, argmax: VisOcclHistGR's paths; its last F1 is the
    host scorer's of the last move, its rewards add up to the F1 gain over the first move (an update's program:
    tests/test_policy_training.py)."""
    from jaxcls.episode import scoring
    from jaxcls.experiments.policy import ppo

    env = episode.replace(config=dataclasses.replace(episode.config, policy=nbv.PolicyName.random))  # (overridden)
    truth = scoring.Truth.from_scene(world.scene, world.object_set)
    truths = jax.tree.map(lambda a: np.stack([a, a]), scoring.TruthArrays.of(truth, episode.spec.num_segments))
    params = {"actor": utility_passed_through(), "critic": learned.init(jax.random.key(1), 8)}
    scene, starts = jnp.zeros(2, jnp.int32), jnp.asarray(start, jnp.int32)
    decided, last = jax.jit(ppo.rollout, static_argnames="sample")(
        params, env, *frames, scene, starts, jax.random.split(jax.random.key(0), 2), truths, sample=False)
    for e in range(2):
        views = [nbv.Views(T_wc=jnp.asarray(frames[1][0]), visited=jnp.zeros(len(world.viewpoints), bool),
                           current=jnp.int32(v)) for v in paper.view[e, :-1]]
        index = np.stack([np.asarray(nbv.candidates(v, episode.nbv_config)[0]) for v in views])
        np.testing.assert_array_equal(index[np.arange(2), np.asarray(decided.action[e])], paper.view[e, 1:])
        f1 = [scoring.candidate_f1(truth, paper.centroid[e, t][None], paper.refinement.valid[e, t][None],
                                   paper.refinement.refined[e, t][None], len(episode.spec.classifier.classes))[0]
              for t in (0, -1)]
        assert float(last[e]) == pytest.approx(f1[1], abs=1e-6)
        assert float(decided.reward[e].sum()) == pytest.approx(f1[1] - f1[0], abs=1e-5)
    config = ppo.PPOConfig(minibatches=8)  # (2 episodes x 2 decisions: 4, refused while tracing, nothing compiled)
    with pytest.raises(ValueError, match=r"4 decisions an update \(2 episodes x 2 after the first move\) cannot fill"):
        ppo.update(params, ppo.optimizer(config).init(params), env, *frames, scene, starts, truths, jax.random.key(0),
                   config)


def test_rollout_labels_are_the_f1_at_the_end_after_the_base_policys_moves():
    """``protocol.Label.rollout``: a candidate's label is its true F1 after the moves the episode's own policy
    (the base) takes from it to T: the label of the base's own second view is the base episode's F1 at T. Picking
    the best label is one step of policy improvement: on the same frames and keys the path ends at least as high
    as the base's. The last decision has no move after it: its labels are one move ahead (the pick is their
    best), or, with ``policy_last``, the pick is the base's own."""
    from jaxcls.episode import scoring

    world = make_world(WORLD, seed=2)  # (with the paper's recipe the candidates' F1 differ, and differ over moves)
    depth, T_wc, _, _ = world.measure(jax.random.PRNGKey(0), np.arange(len(world.viewpoints)))
    settings = dataclasses.replace(SETTINGS, classifier="builtin_paper",  # (the 8 nearest: the 4 within r, and 4)
                                   nbv=dataclasses.replace(SETTINGS.nbv, max_candidates=8))
    episode = setup.make_episode(settings, world.object_set, world.intrinsics, world.table_height)
    truth = scoring.Truth.from_scene(world.scene, world.object_set)
    seen = []

    def tap(states, index, ok, allowed, f1, pick):
        seen.append((states, index, allowed, f1, pick))
        return pick

    # (The first of two runs: one whose best greedy label, 1.0, is 0.5 at the end.)
    start, keys = protocol.start_views(0, 0, 2, len(world.viewpoints))[:1], np.asarray(protocol.run_keys(0, 0, 2))[:1]
    oracle = protocol.oracle_rollouts(episode, depth, T_wc, start, keys, truth, tap=tap, label=protocol.Label.rollout)
    base = batched.rollouts(episode, np.asarray(depth)[None], np.asarray(T_wc, np.float32)[None],
                            np.zeros(1, np.int32), start, keys)
    assert len(seen) == 2  # (3 moves: two decisions)
    classes = len(episode.spec.classifier.classes)

    def last_f1(t):
        """[R] each run's F1 after its last move."""
        return scoring.candidate_f1(truth, t.centroid[:, -1], t.refinement.valid[:, -1], t.refinement.refined[:, -1],
                                    classes)

    states, index, allowed, f1, _ = seen[0]
    ours = np.flatnonzero(index[0] == base.view[0, 1])
    assert len(ours) == 1 and allowed[0, ours[0]], "the base's second view is one of the oracle's candidates"
    assert float(f1[0, ours[0]]) == pytest.approx(last_f1(base)[0], abs=1e-6)
    assert last_f1(oracle)[0] >= last_f1(base)[0] - 1e-6
    # Every candidate's label, move by move (here the greedy label of one of them is 1.0, its rollout's 0.5).
    state, depth, T_wc = jax.tree.map(lambda a: a[0], states), jnp.asarray(depth), jnp.asarray(T_wc, jnp.float32)
    for c in np.flatnonzero(allowed[0]):
        s = active.step_jit(episode, state.replace(next_view=jnp.int32(index[0, c])), depth[index[0, c]],
                            T_wc[index[0, c]])
        s = active.step_jit(episode, s, depth[s.next_view], T_wc[s.next_view])
        t = jax.tree.map(lambda a: np.asarray(a)[None, None], active.trace(s, s.views.current))
        assert float(f1[0, c]) == pytest.approx(last_f1(t)[0], abs=1e-6), c
    last_states, last_index, allowed, f1, pick = seen[1]
    assert f1[0, pick[0]] == np.max(np.where(allowed[0], f1[0], -1.0))
    # ``policy_last`` (the row OracleRolloutGR (InfoGain last)): the same picks but the last, which is the base
    # policy's own choice from there (not the best label: here they differ).
    fair = protocol.oracle_rollouts(episode, depth, T_wc, start, keys, truth, label=protocol.Label.rollout,
                                    policy_last=True)
    policy_view = int(np.asarray(last_states.next_view)[0])
    assert policy_view != int(last_index[0, pick[0]]), "the best label is not the policy's view here"
    np.testing.assert_array_equal(np.asarray(fair.view)[0], [*np.asarray(oracle.view)[0, :-1], policy_view])
    assert protocol.ROWS["oracle_rollout_policy_last_gr"].policy_last


def test_a_rollout_label_needs_a_base_policy():
    from jaxcls.experiments.policy import config

    assert config.load(None, ("labels=rollout",)).labels is protocol.Label.rollout
    with pytest.raises(ValueError, match="labels: rollout continues each candidate with the base policy"):
        config.load(None, ("labels=rollout", "base=none"))


def test_an_episode_without_the_learned_policys_weights_says_so():
    world = make_world(WORLD, seed=1)
    settings = dataclasses.replace(SETTINGS, episode=dataclasses.replace(SETTINGS.episode, policy="learned"))
    with pytest.raises(ValueError, match=r"needs its weights .*a shipped name: real_like, .*real_like_paper_ppo"):
        setup.make_episode(settings, world.object_set, world.intrinsics, world.table_height)
    episode = setup.make_episode(SETTINGS, world.object_set, world.intrinsics, world.table_height)
    assert nbv.PolicyName.learned not in episode.switched().policies
    with pytest.raises(ValueError, match="need their weights"):
        episode.switched(("vis_occl_hist", "learned"))


def test_a_weights_file_of_other_shapes_layout_or_candidate_count_is_refused(tmp_path):
    path = learned.save(tmp_path / "p.msgpack", learned.init(jax.random.key(0), 8), 32, {"trained_on": "test"})
    weights, info = learned.load(path, 32)
    assert info.hidden == 8 and info.max_candidates == 32 and info.metadata == {"trained_on": "test"}
    np.testing.assert_array_equal(np.asarray(weights["params"]["score"]["kernel"]),
                                  np.asarray(learned.init(jax.random.key(0), 8)["params"]["score"]["kernel"]))
    with pytest.raises(ValueError, match=r"p\.json: weights trained with 32 candidates.*max_candidates = 20"):
        learned.load(path, 20)
    meta = json.loads(path.with_suffix(".json").read_text())
    wider = r"p\.msgpack: .*has shape \(8,\), expected \(16,\) for a view policy of width 16"
    for change, message in [({"hidden": 16}, wider),
                            ({"features": 99}, "feature layout 99"), ({"kind": "pointnet"}, "not a view policy"),
                            ({"hidden": "8"}, "'hidden' must be a positive integer")]:
        path.with_suffix(".json").write_text(json.dumps({**meta, **change}))
        with pytest.raises(ValueError, match=message):
            learned.load(path, 32)
    with pytest.raises(FileNotFoundError, match=r"missing\.msgpack not found"):
        learned.load(tmp_path / "missing.msgpack", 32)


def test_the_shipped_policies_load_for_the_moves_planner_and_start_from_infogain():
    """Every shipped policy (``jaxcls train-policy --config policy_NAME``): this layout, the move's candidate count
    (``setup.episode_nbv``), trained from InfoGain for their config's Table 1, classifier and labels; loaded by
    name where a run names them."""
    assert set(learned.SHIPPED_WEIGHTS) == {"real_like", "real_like_paper", "synthetic_paper", "real_like_paper_ppo",
                                            "synthetic_paper_ppo", "real_like_paper_ppo_scenes256",
                                            "real_like_paper_v3", "real_like_paper_v3_scenes256"}
    for name in learned.SHIPPED_WEIGHTS:
        weights, info = learned.load(name, setup.episode_nbv().max_candidates)
        config = load_config(PolicyConfig, resolve_config(f"policy_{name}"))
        assert info.features == config.layout.value and info.metadata["base"] == "info_gain"
        assert config.layout == (learned.Layout.v3 if "_v3" in name else learned.Layout.v2)
        assert info.metadata["table1"] == config.table1 and info.metadata["rounds"] == config.rounds
        assert info.metadata["ppo_updates"] == config.ppo.updates and config.rounds + config.ppo.updates >= 1
        if config.init:  # PPO from a shipped imitation policy: that very file (its digest)
            assert info.metadata["init"] == config.init and config.init in learned.SHIPPED_WEIGHTS
            digest = hashlib.sha256(learned.weights_file(config.init).read_bytes()).hexdigest()
            assert info.metadata["init_sha256"] == digest
        else:  # (imitation from ``base``)
            assert not info.metadata.get("init")
        assert info.metadata["classifier"] == config.classifier == ("shipped" if name == "real_like" else "paper")
        assert info.metadata["labels"] == config.labels.value
        assert weights["params"]["skip"]["kernel"].shape == (learned.CANDIDATE_FEATURES, 1)
        named = setup.policy_weights(dataclasses.replace(setup.episode_nbv(), learned=nbv.Learned(weights=name)))
        assert jax.tree.all(jax.tree.map(lambda a, b: bool(np.array_equal(a, b)), named, weights))


def test_a_table1_row_of_the_learned_policy_needs_its_weights_named_per_classifier_where_they_differ():
    from jaxcls.experiments.table1 import runner
    from jaxcls.experiments.table1.config import Table1Config

    with pytest.raises(ValueError, match=r"rows: learned_gr runs the learned policy; name its weights .*name: real_"):
        Table1Config(rows=("vis_occl_hist_gr", "learned_gr"), classifiers={"shipped": ""})
    named = Table1Config(rows=("learned_gr",), classifiers={"shipped": ""},
                         nbv=dataclasses.replace(nbv.NBVConfig(), learned=nbv.Learned(weights="runs/p/policy.msgpack")))
    assert protocol.ROWS[named.rows[0]].policy == "learned"
    # A policy per classifier (``learned_weights``), each classifier's episodes with its own; one missing is named.
    both = {"shipped": "", "paper": "builtin_paper"}
    with pytest.raises(ValueError, match=r"none for \['shipped'\]"):
        Table1Config(rows=("learned_gr",), classifiers=both, learned_weights={"paper": "real_like_paper"})
    with pytest.raises(ValueError, match=r"learned_weights: \['other'\] not among the classifiers"):
        Table1Config(rows=("learned_gr",), classifiers=both, learned_weights={"other": "real_like_paper"})
    config = Table1Config(rows=("learned_gr",), classifiers=both, learned_weights={"paper": "real_like_paper"},
                          nbv=dataclasses.replace(setup.episode_nbv(), learned=nbv.Learned(weights="real_like")))
    world = make_world(WORLD, seed=1)
    for c, name in (("shipped", "real_like"), ("paper", "real_like_paper")):
        classifier = setup.load_classifier(both[c], world.object_set, f"classifiers.{c}")
        episode = runner.episode(config, protocol.ROWS["learned_gr"], classifier, world.object_set, world.intrinsics,
                                 world.table_height, "test", name=c)
        want = learned.load(name, config.nbv.max_candidates)[0]
        assert jax.tree.all(jax.tree.map(lambda a, b: bool(np.array_equal(a, b)), episode.policy_weights, want))


def test_a_policy_soup_is_the_leafwise_mean_and_refuses_members_of_another_layout_or_candidate_count(tmp_path):
    spec = importlib.util.spec_from_file_location("policy_soup", Path(__file__).parents[1] / "experiments"
                                                  / "policy_soup.py")
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    a, b = learned.init(jax.random.key(1), 8), learned.init(jax.random.key(2), 8)
    pa, pb = (learned.save(tmp_path / f"{n}.msgpack", w, 16, {"classifier": "paper", "base": n})
              for n, w in (("a", a), ("b", b)))
    out = script.main(["--out", str(tmp_path / "soup" / "p.msgpack"), str(pa), str(pb)])
    weights, info = learned.load(out, 16)
    assert info.metadata["classifier"] == "paper" and "base" not in info.metadata  # (what every member says)
    for x, y, z in zip(jax.tree.leaves(a), jax.tree.leaves(b), jax.tree.leaves(weights), strict=True):
        np.testing.assert_allclose(np.asarray(z), (np.asarray(x) + np.asarray(y)) / 2, rtol=1e-6, atol=1e-7)
    members = info.metadata["soup"]
    assert [m["sha256"] for m in members] == [hashlib.sha256(p.read_bytes()).hexdigest() for p in (pa, pb)]
    # A soup of one network with itself is that network, to the bit.
    same = script.main(["--out", str(tmp_path / "same.msgpack"), str(pa), str(pa)])
    for x, z in zip(jax.tree.leaves(a), jax.tree.leaves(learned.load(same, 16)[0]), strict=True):
        np.testing.assert_array_equal(np.asarray(z), np.asarray(x))
    v3 = learned.save(tmp_path / "v3.msgpack", learned.init(jax.random.key(3), 8, layout=learned.Layout.v3), 16)
    with pytest.raises(ValueError, match="feature layouts"):
        script.main(["--out", str(tmp_path / "x.msgpack"), str(pa), str(v3)])
    wide = learned.save(tmp_path / "wide.msgpack", learned.init(jax.random.key(4), 16), 16)
    with pytest.raises(ValueError, match="member 1 has other layers or shapes"):
        script.main(["--out", str(tmp_path / "x.msgpack"), str(pa), str(wide)])
    with pytest.raises(FileNotFoundError, match=r"missing\.json not found"):
        script.main(["--out", str(tmp_path / "x.msgpack"), str(tmp_path / "missing.msgpack"), str(pa)])
    other = learned.save(tmp_path / "k20.msgpack", a, 20)
    with pytest.raises(ValueError, match=r"k20\.json: weights trained with 20 candidates"):
        script.main(["--out", str(tmp_path / "x.msgpack"), str(pa), str(other)])

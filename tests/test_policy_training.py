"""``jaxcls train-policy`` (``experiments.policy``) on a tiny synthetic set on the CPU: the oracle's labels of
every decision, the rounds' fit and held-out evaluation, the weights file; the same seed gives the same numbers,
and a run stopped after a round resumes to the same weights bit for bit."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxcls import viz
from jaxcls.episode import scoring
from jaxcls.experiments.policy import train as policy_train
from jaxcls.experiments.policy.config import PolicyConfig
from jaxcls.experiments.policy.data import Decisions
from jaxcls.experiments.policy.ppo import PPOConfig
from jaxcls.experiments.table1.data import open_scenes
from jaxcls.planning import learned
from jaxcls.world.objects import object_set_from_config


def _table1(tmp: Path) -> Path:
    """A 2-scene, 12-view synthetic set at a quarter of the Kinect's resolution, 2 moves, the 4 nearest views the
    candidates (the suite runs XLA's least optimised programs: the oracle's moves are what takes the time); the
    paper-recipe weights (their labels change from view to view: candidates differ in F1); frames fused at
    the poses given."""
    config = tmp / "table1.yaml"
    config.write_text("dataset: synthetic\nscene_source: device\nruns: 2\nmoves: 2\nscene_chunk: 2\n"
                      "rows: [vis_occl_hist_gr]\nclassifiers: {paper: builtin_paper}\n"
                      "nbv: {radius: 2.0, max_candidates: 4}\n"
                      "perception: {tracking: {mode: reported}}\n"
                      "dataset_overrides: [num_scenes=2, viewpoints.count=12, backend=mujoco, camera.width=160, "
                      "camera.height=120, camera.fx=131.25, camera.fy=131.25, camera.cx=79.5, camera.cy=59.5]\n")
    return config


def _config(tmp: Path, out: str, rounds: int, updates: int = 0, init: str = "",
            layout: learned.Layout = learned.Layout.v3) -> PolicyConfig:
    """(Layout 3 unless said: the first test trains it through imitation and PPO, the window test layout 2.)"""
    return PolicyConfig(out_dir=str(tmp / out), table1=str(_table1(tmp)), train_scenes=2, eval_scenes=1, runs=1,
                        eval_runs=1, rounds=rounds, epochs=4, batch=2, hidden=8, seed=0, init=init, layout=layout,
                        ppo=PPOConfig(updates=updates, epochs=2, minibatches=2, eval_every=1))


def test_gae_is_its_definition():
    from jaxcls.experiments.policy import ppo

    rng = np.random.default_rng(0)
    reward, value = rng.normal(size=(3, 5)), rng.normal(size=(3, 5))
    gamma, lam = 0.9, 0.8
    adv, returns = ppo.advantages(jnp.asarray(reward), jnp.asarray(value), gamma, lam)
    for e in range(3):
        after = np.append(value[e, 1:], 0.0)  # (no value after the last decision)
        delta = reward[e] + gamma * after - value[e]
        want = [sum((gamma * lam) ** (k - t) * delta[k] for k in range(t, 5)) for t in range(5)]
        np.testing.assert_allclose(np.asarray(adv[e]), want, rtol=1e-5)
    np.testing.assert_allclose(np.asarray(returns), np.asarray(adv) + value, rtol=1e-6)


def test_the_groups_baseline_is_the_mean_of_the_other_episodes_return_to_go():
    from jaxcls.experiments.policy import ppo

    rng = np.random.default_rng(1)
    reward = rng.normal(size=(6, 4))  # (2 groups of 3 episodes, 4 decisions)
    gamma = 0.9
    adv, returns = ppo.group_advantages(jnp.asarray(reward), 3, gamma)
    to_go = np.array([[sum(gamma ** (k - t) * reward[e, k] for k in range(t, 4)) for t in range(4)]
                      for e in range(6)])
    np.testing.assert_allclose(np.asarray(returns), to_go, rtol=1e-5)
    for e in range(6):
        others = [o for o in range(3 * (e // 3), 3 * (e // 3) + 3) if o != e]
        np.testing.assert_allclose(np.asarray(adv[e]), to_go[e] - to_go[others].mean(axis=0), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(np.asarray(adv).reshape(2, 3, 4).sum(axis=1), 0.0, atol=1e-5)
    with pytest.raises(ValueError, match="6 episodes do not make groups of 4"):
        ppo.group_advantages(jnp.asarray(reward), 4, gamma)


def test_the_actors_logits_are_its_scores_over_the_temperature_where_allowed():
    from jaxcls.experiments.policy import ppo

    actor = learned.init(jax.random.key(0), 4, "info_gain")
    x = learned.Features(pair=jnp.ones((1, 3, 2, learned.Layout.v2.pair_features)), live=jnp.ones((1, 2), bool),
                         candidate=jax.random.uniform(jax.random.key(1), (1, 3, learned.CANDIDATE_FEATURES)))
    allowed = jnp.array([[True, False, True]])
    scores = learned.apply(actor, x)
    for t in (1.0, 0.25):
        got = ppo.logits(actor, x, allowed, t)
        np.testing.assert_allclose(np.asarray(got[allowed]), np.asarray(scores[allowed]) / t, rtol=1e-6)
        assert float(got[0, 1]) == -1e9


def test_the_loss_is_minus_the_log_probability_of_the_oracles_best_and_scores_regret():
    weights = jax.tree.map(np.zeros_like, jax.device_get(learned.init(jax.random.key(0), 4)))
    x = learned.Features(pair=jnp.zeros((1, 4, 2, learned.Layout.v2.pair_features)), live=jnp.ones((1, 2), bool),
                         candidate=jnp.zeros((1, 4, learned.CANDIDATE_FEATURES)))  # every score 0: uniform
    f1 = jnp.array([[0.5, 0.9, -1.0, 0.2]])
    allowed = jnp.array([[True, True, False, True]])
    value, (regret, agree) = policy_train.loss(weights, x, f1, allowed, 1e-3)
    np.testing.assert_allclose(float(value), np.log(3), rtol=1e-5)  # 1/3 on the best of 3 allowed
    assert float(regret) == pytest.approx(0.9 - 0.5) and float(agree) == 0.0  # (ties: the first, 0.5)
    # Two best of three: -log(2/3), whatever the order among them; all tied: 0, no gradient.
    tied = jnp.array([[0.9, 0.9, -1.0, 0.2]])
    np.testing.assert_allclose(float(policy_train.loss(weights, x, tied, allowed, 1e-3)[0]), np.log(1.5), rtol=1e-5)
    same = jnp.array([[0.7, 0.7, -1.0, 0.7]])
    value, grads = jax.value_and_grad(lambda w: policy_train.loss(w, x, same, allowed, 1e-3)[0])(
        learned.init(jax.random.key(1), 4, "info_gain"))
    assert abs(float(value)) < 1e-6
    assert all(float(jnp.max(jnp.abs(g))) < 1e-6 for g in jax.tree.leaves(grads))
    # A soft temperature: minus the log of the expected exp((F1 - best) / temperature).
    want = -np.log(np.mean(np.exp((np.array([0.5, 0.9, 0.2]) - 0.9) / 0.5)))
    np.testing.assert_allclose(float(policy_train.loss(weights, x, f1, allowed, 0.5)[0]), want, rtol=1e-5)


def _decisions(seed: int, count: int, scenes: int) -> Decisions:
    """``count`` random decisions of 6 candidates (5 allowed) and 3 segments, in layout 2, of ``scenes`` scenes."""
    rng = np.random.default_rng(seed)
    allowed = np.ones((count, 6), bool)
    allowed[:, -1] = False
    f1 = np.where(allowed, rng.random((count, 6)), -1.0).astype(np.float32)
    x = learned.Features(pair=rng.normal(size=(count, 6, 3, learned.Layout.v2.pair_features)).astype(np.float32),
                         live=np.ones((count, 3), bool),
                         candidate=rng.normal(size=(count, 6, learned.CANDIDATE_FEATURES)).astype(np.float32))
    return Decisions(x, f1, allowed, (np.arange(count) % scenes).astype(np.int32))


def test_the_fit_measures_left_out_scenes_each_epoch_and_early_stopping_keeps_the_least_validation_loss():
    """Random labels: what the fit learns of the training scenes' does not carry to the left-out scenes', so
    their loss rises as the fit goes on (overfitting, measured), and early stopping keeps an early epoch of the
    same trajectory, with the figures of the weights it returns."""
    data = _decisions(0, 64, 8)
    train, validation = data.split(np.array([6, 7]))
    assert len(train) == 48 and len(validation) == 16  # (by scene: 8 decisions each)
    assert set(train.scene.tolist()) == set(range(6)) and set(validation.scene.tolist()) == {6, 7}
    weights = learned.init(jax.random.key(0), 16)
    optimizer = policy_train.optax.adam(3e-2)
    key = jax.random.key(1)
    args = (optimizer, train, 12, 8, 0.05, key)
    plain_w, _, plain = policy_train.fit(weights, optimizer.init(weights), *args, validation=validation)
    stop_w, _, stop = policy_train.fit(weights, optimizer.init(weights), *args, validation=validation,
                                       early_stop=True)
    assert plain["val_losses"] == stop["val_losses"] and len(plain["val_losses"]) == 12  # (one trajectory)
    assert plain["epoch"] == 12 and stop["epoch"] == int(np.argmin(stop["val_losses"])) + 1
    assert stop["epoch"] < 12 and stop["val_loss"] == min(stop["val_losses"]) < plain["val_loss"]
    for w, fitted in ((plain_w, plain), (stop_w, stop)):  # (each the loss of the weights it returns)
        value, (regret, agree) = policy_train.loss(w, validation.features, validation.f1, validation.allowed, 0.05)
        assert float(value) == pytest.approx(fitted["val_loss"], rel=1e-5)
        assert float(regret) == pytest.approx(fitted["val_regret"], abs=1e-6)
        assert float(agree) == pytest.approx(fitted["val_agreement"], abs=1e-6)
    # Without validation: the same weights as with it, early stopping off (the validation only measures).
    alone_w, _, alone = policy_train.fit(weights, optimizer.init(weights), *args)
    assert "val_loss" not in alone and alone["loss"] == plain["loss"]
    for a, b in zip(jax.tree.leaves(alone_w), jax.tree.leaves(plain_w), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    with pytest.raises(ValueError, match="early_stop needs validation"):
        policy_train.fit(weights, optimizer.init(weights), *args, early_stop=True)
    unknown = dataclasses.replace(data, scene=np.full(64, -1, np.int32))
    with pytest.raises(ValueError, match="do not say their scene"):
        unknown.split(np.array([7]))
    # The curve: each round's validation loss against the epoch, a dot at the epoch kept; no panel without them.
    history = [{"round": r + 1, "f1_learned": 0.5, **f} for r, f in enumerate((plain, stop))]
    (panel,) = [ax for ax in viz.policy_curve(history).axes if ax.get_xlabel() == "epoch"]
    drawn = [(list(line.get_xdata()), list(line.get_ydata())) for line in panel.get_lines()]
    assert drawn == [(list(range(1, 13)), plain["val_losses"]), ([12], [plain["val_losses"][11]]),
                     (list(range(1, 13)), stop["val_losses"]), ([stop["epoch"]], [stop["val_loss"]])]
    assert len(viz.policy_curve([{"round": 1, "f1_learned": 0.5, **alone}]).axes) == 3  # (loss, its twin, F1)


def test_training_runs_resumes_bit_for_bit_and_writes_a_policy_the_episode_loads(tmp_path, monkeypatch):
    whole = policy_train.train(_config(tmp_path, "whole", 2, updates=1), show_progress=False)
    history = json.loads((whole / "metrics.json").read_text())["history"]
    assert [h.get("round") for h in history] == [1, 2, None] and history[0]["follow_oracle"] == 1.0
    reinforced = history[2]
    assert reinforced["update"] == 1 and 0 <= reinforced["f1_last"] <= 1 and np.isfinite(reinforced["entropy"])
    assert 0 <= reinforced["f1_learned"] <= 1  # (evaluated on the held-out scene)
    assert reinforced["seconds"]["evaluate"] > 0 and reinforced["seconds"]["kept"] > 0  # (the update's other costs)
    history = history[:2]
    decisions = [Decisions.load(whole / f"decisions_{r}.npz") for r in range(2)]
    assert [len(d) for d in decisions] == [2 * 1 * 1] * 2  # scenes x runs x the decisions after move 1
    for d in decisions:
        assert sorted(d.scene.tolist()) == [0, 1]  # (each decision's scene of the training draw)
        assert np.all(d.f1[~d.allowed] == -1) and np.all((d.f1[d.allowed] >= 0) & (d.f1[d.allowed] <= 1))
        assert np.all(np.isfinite(d.features.pair)) and np.all(np.isfinite(d.features.candidate))
    for h in history[:2]:
        assert 0 <= h["regret"] <= 1 and 0 <= h["agreement"] <= 1 and np.isfinite(h["loss"])
        assert 0 <= h["f1_learned"] <= 1 and 0 <= h["f1_vis_occl_hist"] <= 1
        assert len(h["learned_minus_vis_occl_hist"]) == 3 and len(h["learned_minus_info_gain"]) == 3
        assert 0 <= h["f1_info_gain"] <= 1
    weights, info = learned.load(whole / "policy.msgpack", 4)
    assert info.hidden == 8 and info.metadata["rounds"] == 2 and info.metadata["ppo_updates"] == 1
    assert info.features == 3 and all(d.features.pair.shape[-1] == learned.Layout.v3.pair_features
                                       for d in decisions)
    assert info.metadata["labels"] == "greedy" and info.metadata["base"] == "info_gain"
    assert info.metadata["held_out"]["update"] == 1  # (where its held-out figures were measured)
    assert (whole / "curve.png").is_file()
    # Stopped after round 1; run again to 2 rounds and the update, and stopped by a failure in that update (its
    # round 2's policy written already: ``publish``); then run again: the same decisions, figures and weights, bit
    # for bit.
    policy_train.train(_config(tmp_path, "parts", 1), show_progress=False)

    def stopped(*args, **kwargs):
        raise RuntimeError("stopped")

    with monkeypatch.context() as m, pytest.raises(RuntimeError, match="stopped"):
        m.setattr(policy_train.ppo, "update", stopped)
        policy_train.train(_config(tmp_path, "parts", 2, updates=1), show_progress=False)
    _, info = learned.load(tmp_path / "parts" / "policy.msgpack", 4)
    assert info.metadata["rounds"] == 2 and info.metadata["ppo_updates"] == 0
    assert info.metadata["held_out"]["round"] == 2
    for suffix in (".msgpack", ".json"):  # (round 2's policy, kept for PPO alone from it below)
        shutil.copy(tmp_path / "parts" / f"policy{suffix}", tmp_path / f"round2{suffix}")
    parts = policy_train.train(_config(tmp_path, "parts", 2, updates=1), show_progress=False)
    def untimed(rounds):
        return [{k: v for k, v in h.items() if k != "seconds"} for h in rounds]

    assert untimed(json.loads((parts / "metrics.json").read_text())["history"]) == untimed([*history, reinforced])
    assert history[0]["seconds"]["states_per_second"] > 0 and history[1]["seconds"]["fit"] > 0
    for r in range(2):
        again = Decisions.load(parts / f"decisions_{r}.npz")
        np.testing.assert_array_equal(again.f1, decisions[r].f1)
        np.testing.assert_array_equal(again.features.candidate, decisions[r].features.candidate)
    resumed, _ = learned.load(parts / "policy.msgpack", 4)
    for a, b in zip(jax.tree.leaves(weights), jax.tree.leaves(resumed), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    # PPO alone (rounds: 0) from round 2's policy file: the same update and weights as after the rounds that made it.
    alone = policy_train.train(_config(tmp_path, "alone", 0, updates=1, init=str(tmp_path / "round2.msgpack")),
                               show_progress=False)
    start, *rest = json.loads((alone / "metrics.json").read_text())["history"]
    assert untimed(rest) == untimed([reinforced])
    assert start["update"] == 0 and start["f1_learned"] == history[1]["f1_learned"]  # (round 2's policy, evaluated)
    from_file, info = learned.load(alone / "policy.msgpack", 4)
    assert info.metadata["rounds"] == 0 and info.metadata["ppo_updates"] == 1
    assert info.metadata["init"] == str(tmp_path / "round2.msgpack") and len(info.metadata["init_sha256"]) == 64
    for a, b in zip(jax.tree.leaves(weights), jax.tree.leaves(from_file), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    # Its 2 episodes rolled out one after the other (ppo.rollout_batch: 1), not together: the same decisions, so the
    # same F1 and rewards; the update's steps then agree to float32 rounding (a group of 1 is computed in another
    # order than one of 2), which Adam may turn into up to a step apart: each of the 4 steps moves a weight by at
    # most about the learning rate.
    config = _config(tmp_path, "grouped", 0, updates=1, init=str(tmp_path / "round2.msgpack"))
    config = dataclasses.replace(config, ppo=dataclasses.replace(config.ppo, rollout_batch=1))
    grouped = policy_train.train(config, show_progress=False)
    _, one_by_one = json.loads((grouped / "metrics.json").read_text())["history"]
    assert one_by_one["f1_last"] == reinforced["f1_last"] and one_by_one["reward"] == reinforced["reward"]
    assert one_by_one["entropy"] == pytest.approx(reinforced["entropy"], rel=1e-4)
    steps = config.ppo.epochs * config.ppo.minibatches
    for a, b in zip(jax.tree.leaves(from_file), jax.tree.leaves(learned.load(grouped / "policy.msgpack", 4)[0]),
                    strict=True):
        assert np.max(np.abs(np.asarray(b) - np.asarray(a))) <= 2 * steps * config.ppo.learning_rate
    # ppo.group: each run twice, the actor (nearly) greedy. The two episodes of a run then take the same views,
    # their returns are equal and every advantage is 0: the groups hold one scene and start, and the update takes
    # the group's baseline. GAE over a fresh critic (a group of 1, the run above) gives advantages that are not.
    config = _config(tmp_path, "twice", 0, updates=1, init=str(tmp_path / "round2.msgpack"))
    config = dataclasses.replace(config, ppo=dataclasses.replace(config.ppo, group=2, temperature=1e-6))
    _, twice = json.loads((policy_train.train(config, show_progress=False) / "metrics.json").read_text())["history"]
    assert twice["advantage"] == 0.0 and reinforced["advantage"] > 0
    assert 0 <= twice["f1_last"] <= 1
    with pytest.raises(ValueError, match="is a network of width 8; hidden is 4"):  # (refused before it is kept)
        policy_train.train(PolicyConfig(**{**_config(tmp_path, "wide", 0, 1, str(tmp_path / "round2.msgpack"))
                                           .__dict__, "hidden": 4}), show_progress=False)
    assert not (tmp_path / "wide" / "config.yaml").exists()
    with pytest.raises(ValueError, match=r"reads feature layout 3; layout is 2 \(set layout=v3\)"):
        policy_train.train(_config(tmp_path, "older", 0, 1, str(tmp_path / "round2.msgpack"), learned.Layout.v2),
                           show_progress=False)
    with pytest.raises(ValueError, match=r"rounds: 0 and ppo\.updates: 0 train nothing"):
        _config(tmp_path, "x", 0)
    # validation: scene 1's decisions left out of round 1's fit. The scenes rendered a chunk each (scene_chunk: 1):
    # each decision says its scene of the training draw, not its place in its chunk (0 in both).
    config = dataclasses.replace(_config(tmp_path, "held", 1), validation=0.5, early_stop=True,
                                 table1_overrides=("scene_chunk=1",))
    assert config.validation_scenes() == 1
    held = policy_train.train(config, show_progress=False)
    (first,) = json.loads((held / "metrics.json").read_text())["history"]
    collected = Decisions.load(held / "decisions_0.npz")
    assert collected.scene.tolist() == [0, 1]
    np.testing.assert_array_equal(collected.f1, decisions[0].f1)  # (the same labels as in one chunk)
    assert first["decisions"] == 1 and first["val_decisions"] == 1
    assert first["val_loss"] == min(first["val_losses"]) and 0 <= first["val_regret"] <= 1
    value = policy_train.loss(learned.load(held / "policy.msgpack", 4)[0], *jax.tree.map(
        lambda a: a[1:], (collected.features, collected.f1, collected.allowed)), config.temperature)[0]
    assert float(value) == pytest.approx(first["val_loss"], rel=1e-5)  # (scene 1's decision: the one measured)
    with pytest.raises(ValueError, match="early_stop: true picks each round's epoch by the validation loss"):
        dataclasses.replace(_config(tmp_path, "x", 1), early_stop=True)
    with pytest.raises(ValueError, match="leaves no scene to fit on"):
        dataclasses.replace(_config(tmp_path, "x", 1), validation=0.9)
    with pytest.raises(ValueError, match="other settings \\(epochs differ"):
        policy_train.train(PolicyConfig(**{**_config(tmp_path, "parts", 2, 1).__dict__, "epochs": 5}),
                           show_progress=False)
    with pytest.raises(ValueError, match="began its PPO updates after 2 rounds; rounds stays 2"):
        policy_train.train(_config(tmp_path, "parts", 3, 1), show_progress=False)


def test_ppo_slides_its_window_over_the_training_scenes_and_resumes_it_bit_for_bit(tmp_path):
    """``ppo.new_scenes``: update u sees training scenes [u * new, u * new + train_scenes), scene i's frames and
    truth in slot i % train_scenes, the very frames the scene set renders for it; a run grown from 1 update to 2
    (the window made anew at update 2) ends with the weights and figures of a run of 2."""
    def sliding(out: str, updates: int) -> PolicyConfig:
        config = _config(tmp_path, out, 0, updates=updates, layout=learned.Layout.v2)
        return dataclasses.replace(config, ppo=dataclasses.replace(config.ppo, new_scenes=1))

    config = sliding("whole", 2)
    assert config.stream_scenes() == 3 and config.training_config().scenes == 2
    training_config = sliding("unit", 4).training_config()  # (scenes 0-4)
    _, scene_set = open_scenes(training_config)
    object_set = object_set_from_config(scene_set.dataset.objects)
    window = policy_train._Window(policy_train._Scenes(training_config, scene_set, object_set), 1)
    assert window.at(0) == 2 and window.scene == [0, 1]
    assert window.at(2) == 2 and window.scene == [2, 3] and window.at(2) == 0
    assert window.at(3) == 1 and window.scene == [4, 3]  # (scene 4 in the oldest's slot)
    alone = scene_set.chunk([3, 4])
    np.testing.assert_array_equal(np.asarray(window.depth), np.asarray(alone.depth)[::-1])
    np.testing.assert_array_equal(np.asarray(window.T_wc), np.asarray(alone.T_wc, np.float32)[::-1])
    truth = scoring.Truth.from_scene(alone.scenes[1], object_set)
    np.testing.assert_array_equal(window.truths[0].label, truth.label)

    programs = policy_train.ppo.update._cache_size()
    whole = policy_train.train(config, show_progress=False)
    # One program for both updates: the first update's inputs (the init's weights, a fresh critic and optimiser)
    # are placed as the later ones' (the update's outputs), else the second update compiles it again.
    assert policy_train.ppo.update._cache_size() == programs + 1
    policy_train.train(sliding("grown", 1), show_progress=False)
    grown = policy_train.train(sliding("grown", 2), show_progress=False)
    histories = [json.loads((run / "metrics.json").read_text())["history"] for run in (whole, grown)]
    assert [h.get("scenes") for h in histories[0]] == [None, [0, 1], [1, 2]]  # (update 0: the start's evaluation)
    assert [{k: v for k, v in h.items() if k != "seconds"} for h in histories[1]] == \
        [{k: v for k, v in h.items() if k != "seconds"} for h in histories[0]]
    for a, b in zip(jax.tree.leaves(learned.load(whole / "policy.msgpack", 4)[0]),
                    jax.tree.leaves(learned.load(grown / "policy.msgpack", 4)[0]), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    with pytest.raises(ValueError, match=r"ppo\.new_scenes: 3 scenes replaced an update, more than the "
                                         r"train_scenes = 2"):
        dataclasses.replace(config, ppo=dataclasses.replace(config.ppo, new_scenes=3))

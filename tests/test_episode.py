"""The active episode: reset/step are deterministic, the vmapped step is the sequential one, the timed host
path and the scanned rollout give the same episode as the jitted step, the adaptive stop, ``jaxcls run`` on
a recorded sequence, ``jaxcls demo`` (reduced), and bad inputs refused before anything is written."""

from __future__ import annotations

import dataclasses
import json
import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxcls import cli, metrics
from jaxcls.config import ConfigError, load_config
from jaxcls.episode import active, runner, scoring, setup, sources
from jaxcls.geometry import CameraConfig
from jaxcls.perception.settings import PerceptionConfig, ShapeConfig
from jaxcls.perception.tracking import TrackingConfig
from jaxcls.world import recording
from jaxcls.world.dataset import SceneViews
from jaxcls.world.scenes import SceneConfig
from jaxcls.world.setup import WorldConfig, make_world

CAMERA = CameraConfig.kinect_v1(0.5)
SHAPES = ShapeConfig(surface_points=8192, points_per_segment=256)
WORLD = WorldConfig(camera=CAMERA, scene=SceneConfig(num_objects=3), backend="mujoco",
                    viewpoints=dataclasses.replace(WorldConfig().viewpoints, count=40))
MOVES = 3
# The same world and shapes on the command line (one set of compiled programs for the whole file).
SMALL = [*(f"camera.{f.name}={getattr(CAMERA, f.name)}" for f in dataclasses.fields(CAMERA)),
         f"perception.shapes.surface_points={SHAPES.surface_points}",
         f"perception.shapes.points_per_segment={SHAPES.points_per_segment}", "scene.num_objects=3",
         "viewpoints.count=40", "backend=mujoco"]


def _settings(**episode) -> setup.ActiveConfig:
    return setup.ActiveConfig(episode=active.EpisodeConfig(moves=MOVES, **episode),
                              perception=PerceptionConfig(shapes=SHAPES))


@pytest.fixture(scope="module")
def world():
    return make_world(WORLD, seed=1)


@pytest.fixture(scope="module")
def frames(world):
    """Every viewpoint's frame in memory (a dataset scene's ``Preloaded`` source)."""
    depth, T_wc, _, _ = world.measure(jax.random.PRNGKey(0), np.arange(len(world.viewpoints)))
    return sources.Preloaded(depth=depth, T_wc=T_wc, intrinsics=world.intrinsics, table_height=world.table_height,
                             scene=world.scene, name="test scene")


@pytest.fixture(scope="module")
def episode(world):
    return setup.make_episode(_settings(), world.object_set, world.intrinsics, world.table_height)


def _strip_times(log: runner.EpisodeLog) -> list[dict]:
    return [{k: v for k, v in m.items() if k != "times_ms"} for m in log.moves]


def test_same_seed_same_episode(episode, world, frames):
    truth = scoring.Truth.from_scene(world.scene, world.object_set)
    a = runner.run(episode, frames, 5, jax.random.PRNGKey(3), truth)
    b = runner.run(episode, frames, 5, jax.random.PRNGKey(3), truth)
    assert len(a.moves) == MOVES and a.path[0] == 5 and len(set(a.path)) == MOVES  # never fuses a view twice
    assert _strip_times(a) == _strip_times(b)
    assert set(a.moves[0]["times_ms"]) == set(active.MODULES)
    assert all(m["segments"] for m in a.moves) and all(0 <= m["scores"]["refined"]["f1"] <= 1 for m in a.moves)
    # The record's scores are the metrics of its labels against the scene; phantoms only lower the F1.
    last = a.moves[-1]
    assert last["detection"]["segments"] == len(last["segments"]) and last["detection"]["objects"] == len(truth.label)
    assert all(m["detection"]["f1"] <= m["scores"]["refined"]["f1"] + 1e-9 for m in a.moves)
    classes = list(episode.spec.classifier.classes)
    for m in a.moves:  # the target objects' labels, and each phantom a detection of no object
        phantom = np.array([classes.index(c) for c in m["detection"]["phantoms"]], np.int64)
        true = np.concatenate([truth.label[truth.target], np.full(len(phantom), -1)])
        predicted = np.concatenate([np.asarray(m["labels"]["refined"])[truth.target], phantom])
        assert m["detection"]["f1"] == round(metrics.classification_scores(true, predicted, len(classes)).f1, 4)
    assert 0 < np.mean(last["coverage"]) <= 1


def _assert_states_equal(a, b, atol=1e-5, rho_atol=0.0):
    """Same state: integers exact, floats close. With ``rho_atol`` > 0 (a vmapped program: XLA orders its
    reductions otherwise, and ICP can settle a losing candidate in another of two near-equal minima), rho
    may move by that much, and a segment whose two best candidates lie within it (a tie) may take either:
    its label, model, pose and stability are not compared."""
    rho_a, rho_b = np.asarray(a.refinement.rho), np.asarray(b.refinement.rho)
    np.testing.assert_allclose(rho_a, rho_b, atol=rho_atol + 1e-6)
    top = np.sort(rho_b, axis=1)
    tie = (top[:, -1] - top[:, -2] <= 2 * rho_atol) if rho_atol > 0 else np.zeros(len(top), bool)
    assert (~tie).sum() >= 2, "fewer than two untied segments: the comparison says little"

    # The class evidence sums each move's rho (x probability): it may move by rho's tolerance per move.
    np.testing.assert_allclose(np.asarray(a.evidence), np.asarray(b.evidence), atol=MOVES * rho_atol + 1e-5)

    def untied(state):
        r = state.refinement
        keep = jnp.asarray(~tie)
        return state.replace(stable=jnp.where(keep, state.stable, 0), evidence=0, refinement=r.replace(
            rho=0, refined=jnp.where(keep, r.refined, 0), model=jnp.where(keep, r.model, 0),
            pose=jnp.where(keep[:, None, None], r.pose, 0)))

    for x, y in zip(jax.tree.leaves(untied(a)), jax.tree.leaves(untied(b)), strict=True):
        x, y = np.asarray(x), np.asarray(y)
        if x.dtype.kind in "biu":
            np.testing.assert_array_equal(x, y)
        else:
            np.testing.assert_allclose(x, y, atol=atol, rtol=1e-4)


@pytest.mark.optimised  # (two programs of the same move compared to their last digits)
def test_the_timed_host_path_and_the_jitted_step_agree(episode, frames):
    key = jax.random.PRNGKey(0)
    jitted = timed = active.reset(episode, frames.viewpoints, 7, key)
    for _ in range(2):
        depth, T_wc = frames.frame(int(jitted.next_view))
        jitted = active.step_jit(episode, jitted, depth, T_wc.astype(np.float32))
        timed, times = active.timed_step(episode, timed, depth, T_wc.astype(np.float32))
        _assert_states_equal(jitted, timed)
        assert all(t > 0 for t in times.values())


def test_the_stages_name_their_operations(episode, frames):
    """Each stage of a move runs under its name (``jax.named_scope``): XLA's op names carry it, so a profile
    of the compiled move attributes its kernels to stages (``benchmarks/profile_batched.py``)."""
    state = active.reset(episode, frames.viewpoints, 3, jax.random.PRNGKey(5))
    depth, T_wc = frames.frame(int(state.next_view))
    text = active.step_jit.lower(episode, state, depth, T_wc.astype(np.float32)).as_text(debug_info=True)
    for name in active.MODULES:
        assert f"/{name}/" in text, name


def test_moves_after_the_first_compile_nothing(episode, frames):
    """Three moves of the timed host path (``jaxcls run``'s): after move 1 no jitted stage traces (hence
    compiles) again; a state leaf that changed its type across a move (e.g. a weakly typed ``rho`` from a
    count divided by a Python float) would compile every stage it enters a second time."""
    programs = [active._arrive_jit, active.step_jit, *active._STAGE_JITS.values()]
    state = active.reset(episode, frames.viewpoints, 3, jax.random.PRNGKey(5))
    sizes = []
    for _ in range(3):
        depth, T_wc = frames.frame(int(state.next_view))
        state, _ = active.timed_step(episode, state, depth, T_wc.astype(np.float32))
        sizes.append([p._cache_size() for p in programs])
    assert sizes[1] == sizes[0] and sizes[2] == sizes[0], sizes


@pytest.mark.optimised  # (two programs of the same move compared to their last digits)
def test_vmapped_step_equals_the_sequential_one(world, frames):
    """Two episodes (other starts, other keys) stepped together under vmap give what stepping each gives,
    move after move (each move from the same states). Frames fused at the poses given: a tracked pose differs
    from the sequential one in its last float32 digits, which moves the fused surface chaotically downstream
    (``tracking.track`` under vmap is checked in test_tracking.py)."""
    perception = PerceptionConfig(shapes=SHAPES, tracking=TrackingConfig(mode="reported"))
    episode = setup.make_episode(dataclasses.replace(_settings(), perception=perception), world.object_set,
                                 world.intrinsics, world.table_height)
    starts, keys = [3, 21], [jax.random.PRNGKey(1), jax.random.PRNGKey(2)]
    alone = [active.reset(episode, frames.viewpoints, s, k) for s, k in zip(starts, keys, strict=True)]
    vstep = jax.jit(jax.vmap(active.step, in_axes=(None, 0, 0, 0)))
    for _ in range(MOVES):
        views = [int(s.next_view) for s in alone]
        depth = np.stack([frames.frame(v)[0] for v in views])
        T_wc = np.stack([frames.frame(v)[1] for v in views]).astype(np.float32)
        batch = vstep(episode, jax.tree.map(lambda *a: jnp.stack(a), *alone), depth, T_wc)
        alone = [active.step_jit(episode, s, d, T) for s, d, T in zip(alone, depth, T_wc, strict=True)]
        for i, s in enumerate(alone):
            _assert_states_equal(jax.tree.map(lambda a, i=i: a[i], batch), s, atol=1e-4, rho_atol=0.02)
    assert [int(s.path[0]) for s in alone] == starts


def test_the_scanned_rollout_is_the_host_run(episode, frames):
    """The whole episode under one lax.scan on the frames in memory visits the views the host run visits
    and ends with the same labels."""
    log = runner.run(episode, frames, 11, jax.random.PRNGKey(4))
    state = active.reset(episode, frames.viewpoints, 11, jax.random.PRNGKey(4))
    final, trace = active.rollout_jit(episode, state, frames.depth, frames.T_wc.astype(np.float32))
    assert np.asarray(trace.view).tolist() == log.path
    assert np.asarray(final.path).tolist() == log.path
    refined = [log.classes.index(s["refined"]) for s in log.moves[-1]["segments"]]
    assert np.asarray(final.refinement.refined)[np.asarray(final.refinement.valid)].tolist() == refined
    assert bool(final.done) and not np.asarray(trace.done).any()


def test_a_stopped_episode_comes_back_unchanged(episode, frames):
    """``step`` on a state already done returns it leaf for leaf; its volume is left where it is (the frame is
    fused as one without returns), not selected between two copies."""
    state = active.reset(episode, frames.T_wc, 0, jax.random.PRNGKey(0))
    state = active.step_jit(episode, state, *frames.frame(0)).replace(done=jnp.asarray(True))
    after = active.step_jit(episode, state, *frames.frame(5))
    for path, (a, b) in zip(jax.tree_util.tree_leaves_with_path(state), zip(jax.tree.leaves(state),
                                                                              jax.tree.leaves(after), strict=True),
                            strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=jax.tree_util.keystr(path[0]))
    assert np.asarray(state.observation.volume.weight).sum() > 0


def test_gr_off_keeps_the_prior_and_the_adaptive_stop_ends_early(world, frames):
    """(Both episodes fuse their frames at the poses given: tracking is not the subject here, and each episode's
    programs compile in about half the time.)"""
    untracked = PerceptionConfig(shapes=SHAPES, tracking=TrackingConfig(mode="reported"))

    def settings(**episode) -> setup.ActiveConfig:
        return dataclasses.replace(_settings(**episode), perception=untracked)

    off = setup.make_episode(settings(refinement=False), world.object_set, world.intrinsics, world.table_height)
    log = runner.run(off, frames, 2, jax.random.PRNGKey(0))
    assert all(s["prior"] == s["refined"] and s["rho"] == [0.0] * len(s["rho"]) for m in log.moves
               for s in m["segments"])
    stop = setup.make_episode(settings(stop=active.StopConfig(stable_moves=1, min_rho=0.0)), world.object_set,
                              world.intrinsics, world.table_height)
    log = runner.run(stop, frames, 2, jax.random.PRNGKey(0))
    assert len(log.moves) == 1 and log.moves[0]["stop"]  # every class has held for one move: stop at once


def test_the_continuous_policy_goes_off_the_fixed_viewpoints(world, frames):
    """With off_grid, the second frame is rendered where the continuous policy's ascent ended (not at a
    viewpoint); the nearest viewpoint keeps the books. A source of recorded frames cannot do that."""
    off = setup.make_episode(_settings(policy="continuous", off_grid=True), world.object_set, world.intrinsics,
                             world.table_height)
    log = runner.run(off, sources.Rendered(world, jax.random.PRNGKey(0)), 2, jax.random.PRNGKey(0))
    first, second = log.moves[0], log.moves[1]
    np.testing.assert_allclose(first["camera"], world.viewpoints[2, :3, 3], atol=1e-4)
    # Where the frame was fused: the tracked pose, within 2 mm of where the camera was sent (exact poses).
    np.testing.assert_allclose(second["camera"], first["next_camera"], atol=2e-3)
    grid = np.linalg.norm(world.viewpoints[:, :3, 3] - np.asarray(second["camera"]), axis=-1)
    assert grid.min() > 1e-3 and second["view"] == int(grid.argmin())  # off the grid; its nearest viewpoint
    assert second["segments"]
    with pytest.raises(ValueError, match="off_grid"):
        runner.run(off, frames, 2, jax.random.PRNGKey(0))
    with pytest.raises(ValueError, match=r"off_grid needs episode\.policy=continuous"):
        active.EpisodeConfig(off_grid=True)


def test_run_accepts_a_recorded_sequence_and_scores_it(tmp_path, world, frames, capsys):
    folder = recording.write_recording(tmp_path / "rec", recording.Recording(
        depth=frames.depth[:12], T_wc=frames.T_wc[:12], intrinsics=world.intrinsics, table_height=world.table_height,
        scene=world.scene.to_dict()))
    out = tmp_path / "out"
    assert cli.main(["run", *SMALL, f"source={folder}", "start=4", "episode.moves=2", f"out_dir={out}"]) == 0
    printed = capsys.readouterr().out
    assert "move  1  view   4 -> next" in printed and "move  2" in printed
    log = json.loads((out / "episode.json").read_text())
    assert log["start"] == 4 and len(log["moves"]) == 2 and all(0 <= m["next_view"] < 12 for m in log["moves"])
    assert "scores" in log["moves"][0] and (out / "report.md").is_file() and (out / "curves.png").is_file()
    assert "yaw_source: learned" in (out / "config.yaml").read_text()  # what ran: refine.yaw_source=auto resolved


def test_an_episode_recorded_for_rerun(tmp_path, episode, world, frames):
    """Each move's candidates and utilities as the planner weighed them (its choice is their best within the
    radius), and the .rrd as rerun reads it: every entity once a move, the truth once."""
    from jaxcls.episode.viewer import EpisodeRecording, entity_rows

    recorder = EpisodeRecording(episode, frames.T_wc, episode.spec.classifier.classes, world.scene, world.object_set)
    chosen = []
    utilities = jax.jit(active.candidate_utilities)  # (one compiled program, not its operations one by one)

    def on_move(record, state, depth, T_wc):
        index, ok, U = (np.asarray(x) for x in utilities(episode, state))
        assert np.isfinite(U).all() and ok.any()
        chosen.append((int(index[np.argmax(np.where(ok, U, -np.inf))]), int(state.next_view)))
        recorder.move(record, state, depth, T_wc)

    log = runner.run(episode, frames, 5, jax.random.PRNGKey(3), on_move=on_move)
    assert [a for a, _ in chosen] == [b for _, b in chosen] == [m["next_view"] for m in log.moves]
    rows = entity_rows(recorder.write(tmp_path / "episode.rrd"))
    per_move = ["/world/camera/depth", "/world/path", "/world/candidates", "/world/next_view",
                "/world/segments/by_class", "/world/segments/by_segment", "/world/models", "/objects/segment_0/rho"]
    assert {e: rows.get(e) for e in per_move} == dict.fromkeys(per_move, MOVES)
    assert rows["/world/camera"] == 2 * MOVES  # its pose and its pinhole
    assert rows["/truth/objects"] == 1


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory):
    """``jaxcls demo`` reduced (2 moves): its folder and what it printed."""
    import contextlib
    import io

    out, printed = tmp_path_factory.mktemp("demo") / "demo", io.StringIO()
    with contextlib.redirect_stdout(printed):
        assert cli.main(["demo", *SMALL, "episode.moves=2", f"out_dir={out}"]) == 0
    return out, printed.getvalue()


def test_demo_runs_reduced(demo_run):
    out, printed = demo_run
    assert sorted(p.name for p in (out / "moves").iterdir()) == ["move_01.png", "move_02.png"]
    from jaxcls.episode.viewer import entity_rows

    assert entity_rows(out / "episode.rrd")["/world/camera/depth"] == 2  # the demo records for rerun by default
    report = (out / "report.md").read_text()
    assert "## Objects after the last move" in report and "vis_occl_hist" in report
    assert "segment" in printed


def _colour_codes(shot: np.ndarray) -> np.ndarray:
    """Each pixel's colour of a screenshot [H, W, 3] as one integer (R, G, B in 0..255: 0x00RRGGBB): the same
    distinct colours as its RGB rows, counted in a tenth of the time (``np.unique`` of rows, ``axis=0``, took ~1 s
    a screenshot, each second of the wait for the page)."""
    rgb = shot.reshape(-1, 3).astype(np.int32)
    return (rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2]


def browser_screenshot(url: str, path, timeout: float = 90.0) -> np.ndarray:
    """``url`` loaded in headless Chromium (Debian's, through Playwright) until the page has drawn and holds
    still: its screenshot [H, W, 3] (also written to ``path``)."""
    import shutil
    import time

    from PIL import Image

    chromium = next((shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome") if shutil.which(n)),
                    None)
    if chromium is None:
        pytest.skip("no Chromium installed (Debian: apt-get install chromium): the web viewer is not opened")
    sync_api = pytest.importorskip("playwright.sync_api", reason="Playwright (pip install playwright) drives Chromium")
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium, args=[
            "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"])
        page = browser.new_page(viewport={"width": 1400, "height": 900})
        page.goto(url)
        before, deadline = None, time.monotonic() + timeout
        while time.monotonic() < deadline:
            time.sleep(1.0)
            # (a screenshot may wait for a frame long past Playwright's 30 s on a loaded 2-core CPU: up to the deadline)
            page.screenshot(path=str(path), timeout=1000 * max(30.0, deadline - time.monotonic()))
            shot = np.asarray(Image.open(path).convert("RGB")).astype(np.int16)
            drawn = len(np.unique(_colour_codes(shot))) > 1000
            if drawn and before is not None and np.mean(np.abs(shot - before) > 8) < 0.002:
                break
            before = shot
        browser.close()
    return shot


def test_the_demo_in_a_browser(demo_run, tmp_path):
    """The demo's recording served by ``jaxcls view --web``'s server and opened in headless Chromium: the web
    viewer draws the episode (its 3-D scene, depth frame and curves: a screenshot of many colours, most of the
    page not the empty background). ``JAXCLS_SCREENSHOT=docs/viewer_move.png`` keeps the screenshot (README)."""
    from jaxcls.commands.view import free_ports, serve_web

    out, _ = demo_run
    with serve_web(out / "episode.rrd", free_ports()) as url:
        shot = browser_screenshot(url, tmp_path / "viewer.png")
    colours, counts = np.unique(_colour_codes(shot), return_counts=True)
    assert len(colours) > 1000, "the viewer drew next to nothing"
    assert counts.max() < 0.8 * counts.sum(), "the page is mostly one colour: the episode was not drawn"
    if os.environ.get("JAXCLS_SCREENSHOT"):
        import shutil

        shutil.copy(tmp_path / "viewer.png", os.environ["JAXCLS_SCREENSHOT"])


# --- bad inputs: clear errors naming the file or key, nothing written -----------------------------------------

def test_class_evidence_sums_or_keeps_the_best_and_a_bad_move_cannot_overturn_it():
    """``active.gather_evidence`` over one object's moves (classes A, B, C): three moves favour A (0.5), then C
    is seen well (0.9, 0.9). The sum ("evidence") turns to C once C's total passes A's, the best score
    ("best") as soon as C's single score beats A's; a move fitting everything badly (0.1 each) changes neither
    decision; decay 0 is the last move alone; the sum with decay 1 is the plain sum of the moves."""
    moves = jnp.asarray([[0.5, 0.0, 0.1], [0.5, 0.0, 0.0], [0.5, 0.1, 0.0], [0.0, 0.0, 0.9], [0.1, 0.1, 0.1],
                         [0.0, 0.0, 0.9]], jnp.float32)[:, None, :]  # [moves, N=1, M=3]

    def decisions(**config):
        config = active.EpisodeConfig(**config)
        evidence, out = jnp.zeros((1, 3), jnp.float32), []
        for move in moves:
            evidence = active.gather_evidence(config, evidence, move)
            out.append(int(jnp.argmax(evidence[0])))
        return out, evidence

    A, C = 0, 2
    summed, total = decisions(decision="evidence")
    np.testing.assert_allclose(np.asarray(total), np.asarray(moves.sum(0)), atol=1e-6)
    assert summed == [A, A, A, A, A, C]  # C's 1.8 passes A's 1.6 at the sixth move; the bad fifth changes nothing
    assert decisions(decision="best")[0] == [A, A, A, C, C, C]
    assert decisions(decision="evidence", evidence_decay=0.0)[0] == [int(jnp.argmax(m[0])) for m in moves]
    assert decisions(decision="evidence", evidence_decay=0.5)[0][3] == C  # A's 0.875 fades below C's 0.9


def test_moves_zero_and_unknown_policy_are_config_errors():
    from jaxcls.commands.run import RunConfig

    with pytest.raises(ConfigError, match=r"episode\.moves"):
        load_config(RunConfig, None, ["episode.moves=0"])
    with pytest.raises(ConfigError, match=r"episode\.policy.*Invalid value 'best', expected one of \[random, "):
        load_config(RunConfig, None, ["episode.policy=best"])


def test_a_dataset_file_of_another_object_set_or_camera_is_refused(tmp_path, world, frames):
    views = SceneViews(scene=world.scene, intrinsics=world.intrinsics, depth=frames.depth[:2],
                       object_id=np.zeros(frames.depth[:2].shape, np.int16), T_wc=frames.T_wc[:2],
                       T_wc_true=frames.T_wc[:2])
    path = views.save(tmp_path / "scene_000.npz")
    other = dataclasses.replace(world.config.objects, seed=1)  # another draw of the built-in families
    with pytest.raises(ValueError, match=r"scene_000.npz: the scene was drawn from objects"):
        sources.dataset_source(path, other, world.intrinsics)
    with pytest.raises(ValueError, match=r"scene_000.npz: key 'intrinsics'"):
        sources.dataset_source(path, world.config.objects, CameraConfig().intrinsics())


def test_bad_runs_write_nothing(tmp_path, world, frames, capsys):
    """A start view out of range, a classifier of other classes, a recording with a frame missing."""
    folder = recording.write_recording(tmp_path / "rec", recording.Recording(
        depth=frames.depth[:3], T_wc=frames.T_wc[:3], intrinsics=world.intrinsics, table_height=world.table_height))
    out = tmp_path / "out"
    assert cli.main(["run", *SMALL, f"source={folder}", "start=3", f"out_dir={out}"]) == 2
    assert "start: view 3 is outside 0..2" in capsys.readouterr().err
    (folder / "depth" / "000001.png").unlink()
    assert cli.main(["run", *SMALL, f"source={folder}", f"out_dir={out}"]) == 2
    assert "000001.png" in capsys.readouterr().err
    weights = tmp_path / "w.msgpack"
    from jaxcls.perception import pointnet

    shipped = pointnet.load_classifier()
    pointnet.save_classifier(weights, dataclasses.replace(shipped, classes=tuple(f"c{i}" for i in shipped.classes)))
    assert cli.main(["run", *SMALL, f"classifier={weights}", f"out_dir={out}"]) == 2
    err = capsys.readouterr().err
    assert "w.msgpack" in err and "trained on classes" in err
    assert not out.exists()
    with pytest.raises(ValueError, match=r"start view 40 is outside 0\.\.39"):
        active.reset(setup.make_episode(_settings(), world.object_set, world.intrinsics, world.table_height),
                     world.viewpoints, 40, jax.random.PRNGKey(0))

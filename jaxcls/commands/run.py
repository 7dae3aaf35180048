"""``jaxcls run``: one active episode (one scene or a recorded sequence, one policy), each move printed, and
a report folder; ``jaxcls demo`` is the same on the embedded default (``configs/demo.yaml``), with pictures.

Sources (``source``): "" draws scene ``seed`` of the config's world and renders it on demand; a
``scene_NNN.npz`` of ``jaxcls dataset`` (or a dataset folder with ``scene_index``); a recording folder
(``world.recording``'s format: the real-robot path); a ROS bag (``world.rosbag``: topics and frames in
``bag.*``). The report folder (written whole at the end, never
half; an existing one is kept and the run goes beside it, see ``show.free_folder``)::

    <out_dir>/
      config.yaml     the resolved config
      episode.json    every move's record (``episode.runner``) and the scene's objects
      report.md       "N of M objects right", the final per-object table against the truth, the per-move table
      curves.png      F1 and accuracy over moves, prior and refined (with a scene to score against)
      moves/move_NN.png   with ``pictures``: depth, segments by refined class, aligned cuboids, the views
      episode.rrd     with ``rerun``: every move in 3-D for rerun's viewer (``jaxcls view``; ``episode.viewer``)
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path
from typing import Any

import numpy as np

from jaxcls.commands import Argument, Command
from jaxcls.config import bounded, check_bounds
from jaxcls.episode.setup import ActiveConfig
from jaxcls.world.rosbag import BagConfig, is_bag
from jaxcls.world.setup import WorldConfig


@dataclasses.dataclass(frozen=True)
class RunConfig(ActiveConfig, WorldConfig):
    """``jaxcls run`` / ``jaxcls demo``: the world (a scene drawn and rendered on demand) or a ``source`` file,
    the episode's blocks (``ActiveConfig``), where it starts and where the report goes."""

    source: str = ""  # "": render scene `seed`; a dataset scene .npz or folder; a recording folder; a ROS bag
    bag: BagConfig = dataclasses.field(default_factory=BagConfig)  # a ROS bag source's topics and frames
    scene_index: int = bounded(0, ge=0)  # the scene of a dataset folder
    seed: int = bounded(0, ge=0, lt=2**32)  # the scene drawn (source "") and the episode's key: 32-bit unsigned
    start: int = bounded(0, ge=0)  # the first viewpoint
    out_dir: str = "runs/run"
    pictures: bool = False  # a picture per move in <out_dir>/moves
    rerun: bool = False  # the episode in 3-D for rerun's viewer: <out_dir>/episode.rrd (jaxcls view <out_dir>)

    def __post_init__(self) -> None:
        check_bounds(self)


def open_source(config: RunConfig, object_set):
    """The ``ViewSource`` of ``config.source`` (errors name the file or folder and what is wrong)."""
    import jax

    from jaxcls.episode import sources
    from jaxcls.world.dataset import scene_file
    from jaxcls.world.setup import make_world

    if not config.source:
        world = make_world(config.world_config(), config.seed, object_set=object_set)
        return sources.Rendered(world, jax.random.PRNGKey(config.seed))
    path = Path(config.source)
    if is_bag(path):
        return sources.bag_source(path, config.bag)
    if path.is_file():
        return sources.dataset_source(path, config.objects, config.camera.intrinsics())
    if (path / "meta.json").is_file() or (path / "depth").is_dir():
        return sources.recording_source(path, config.objects)
    if (path / "config.yaml").is_file():
        return sources.dataset_source(scene_file(path, config.scene_index), config.objects, config.camera.intrinsics())
    raise ValueError(f"source: {config.source} is neither a scene file (.npz), a dataset folder (config.yaml), a "
                     "recording folder (meta.json) nor a ROS bag (a folder with metadata.yaml, or a .bag file)")


def _object_table(log) -> list[tuple]:
    """The final move's label of each scene object against the truth."""
    last = log.moves[-1]
    rows = []

    def name(c: int) -> str:
        return log.classes[c] if c >= 0 else "(no segment)"

    for k, obj in enumerate(log.objects):
        prior, refined = last["labels"]["prior"][k], last["labels"]["refined"][k]
        rows.append((obj["name"], obj["class"], "target" if obj["target"] else "clutter", name(prior), name(refined),
                     ("yes" if refined >= 0 and log.classes[refined] == obj["class"] else "no") if obj["target"]
                     else "", f"{last['coverage'][k]:.2f}"))
    return rows


def right_counts(log) -> dict[str, tuple[int, int]]:
    """{"prior": (right, targets), "refined": (right, targets)} after the last move: the target objects whose
    label is their class (clutter is never scored)."""
    last = log.moves[-1]
    targets = [k for k, obj in enumerate(log.objects) if obj["target"]]

    def right(labels: list[int]) -> int:
        return sum(labels[k] >= 0 and log.classes[labels[k]] == log.objects[k]["class"] for k in targets)

    return {kind: (right(last["labels"][kind]), len(targets)) for kind in ("prior", "refined")}


def right_line(log) -> str:
    """The report's tally of the target objects: "**3 of 5 objects right** after 10 moves (refined class; ...)"."""
    counts = right_counts(log)
    (n, m), (n_prior, _) = counts["refined"], counts["prior"]
    clutter = sum(not obj["target"] for obj in log.objects)
    how = f"refined class; PointNet's prior class: {n_prior} of {m}" if log.refinement else "GR off: PointNet's class"
    moves = len(log.moves)
    return (f"**{n} of {m} objects right** after {moves} move{'s' if moves != 1 else ''} ({how}"
            + (f"; {clutter} clutter objects, never scored)" if clutter else ")"))


def report_markdown(source_name: str, log, summary: dict[str, Any]) -> str:
    """``report.md`` of an episode: what ran, with a scene the tally (``right_line``) and the per-object table
    against the truth, then the per-move table."""
    from jaxcls import report
    from jaxcls.episode import active

    scored = bool(log.moves) and "scores" in log.moves[-1]
    lines = [f"# Episode: {source_name}", "",
             f"policy `{log.policy}`, GR {'on' if log.refinement else 'off'}, start view {log.start}, "
             f"{len(log.moves)} moves, path {summary['path_length_m']:.2f} m", ""]
    if scored:
        lines += ["## Objects after the last move", "", right_line(log), "", report.table(
            ("object", "class", "role", "prior", "refined", "right", "coverage"), _object_table(log)), ""]
    lines += ["## Moves", "", report.table(
        ("move", "view", "next", *(f"{k} ms" for k in active.MODULES),
         *(("F1 prior", "F1 refined") if scored else ())),
        [(m["move"], m["view"], m["next_view"], *(f"{m['times_ms'][k]:.1f}" for k in active.MODULES),
          *((f"{m['scores']['prior']['f1']:.3f}", f"{m['scores']['refined']['f1']:.3f}") if scored else ()))
         for m in log.moves])]
    return "\n".join(lines) + "\n"


def run_command(config: RunConfig, overwrite: bool = False, echo=print) -> tuple[Path, Any]:
    """Run the episode of ``config``, ``echo`` each move, write the report folder; returns (folder, log).
    Every input is checked before the first move (out_dir, source, classifier, start view)."""
    import jax

    from jaxcls import io, viz
    from jaxcls.commands.show import free_folder
    from jaxcls.config import save_config
    from jaxcls.episode import active, runner, scoring, setup
    from jaxcls.world.objects import object_set_from_config

    # First: an out_dir that is a file or cannot be written is refused before anything is computed.
    io.check_out_dir(config.out_dir, whole=True)
    object_set = object_set_from_config(config.objects)
    source = open_source(config, object_set)
    classifier = setup.load_classifier(config.classifier, object_set, "key 'classifier'")
    if config.start >= len(source.viewpoints):
        raise ValueError(f"start: view {config.start} is outside 0..{len(source.viewpoints) - 1} "
                         f"({len(source.viewpoints)} viewpoints in {source.name})")
    episode = setup.make_episode(config.active_config(), object_set, source.intrinsics, source.table_height,
                                 classifier, config.scene.split)
    truth = scoring.Truth.from_scene(source.scene, object_set) if source.scene is not None else None
    figures = []
    viewer = None
    if config.rerun:
        from jaxcls.episode.viewer import EpisodeRecording

        viewer = EpisodeRecording(episode, source.viewpoints, episode.spec.classifier.classes, source.scene,
                                  object_set, name=source.name)

    def on_move(record, state, depth, T_wc):
        echo(runner.describe(record))
        if config.pictures:
            figures.append((record, runner.picture_data(episode, state, depth, T_wc)))
        if viewer is not None:
            viewer.move(record, state, depth, T_wc)

    echo(f"episode: {source.name}, policy {config.episode.policy}, GR {'on' if config.episode.refinement else 'off'}, "
         f"start view {config.start}, up to {config.episode.moves} moves (the first move compiles)")
    log = runner.run(episode, source, config.start, jax.random.PRNGKey(config.seed), truth, on_move=on_move)
    summary = {"moves": len(log.moves), "path_length_m": round(runner.path_length(log, source.viewpoints), 4),
               "median_ms_per_move_after_the_first": {k: float(np.median([m["times_ms"][k] for m in log.moves[1:]]))
                                                      for k in active.MODULES} if len(log.moves) > 1 else {}}
    out = free_folder(config.out_dir, overwrite)
    with io.atomic_folder(out) as tmp:
        save_config(dataclasses.replace(config, refine=episode.refine_config), tmp / "config.yaml")  # what ran
        io.write_json(tmp / "episode.json", {**log.to_dict(), "summary": summary})
        io.write_text(tmp / "report.md", report_markdown(source.name, log, summary))
        if viewer is not None:
            viewer.write(tmp / "episode.rrd")
        if truth is not None:
            viz.save(viz.episode_curves({"F1 refined": log.curve("refined"), "F1 prior": log.curve("prior"),
                                         "accuracy refined": log.curve("refined", "accuracy"),
                                         "accuracy prior": log.curve("prior", "accuracy")}), tmp / "curves.png")
        for record, data in figures:
            title = (f"move {record['move']}: view {record['view']} -> next {record['next_view']}"
                     + (f"   F1 refined {record['scores']['refined']['f1']:.2f}" if "scores" in record else ""))
            viz.save(viz.episode_move(title, **data, viewpoints=source.viewpoints, classes=log.classes),
                     tmp / "moves" / f"move_{record['move']:02d}.png")
    return out, log


def _run(config: RunConfig, args: argparse.Namespace) -> str:
    from jaxcls import precision

    precision.full_float32_matmuls()  # no TF32 on a GPU (jaxcls.precision)
    out, log = run_command(config, overwrite=args.overwrite, echo=lambda line: print(line, flush=True))
    final = log.moves[-1]
    score = ""
    if "scores" in final:
        score = (f"; final F1 {final['scores']['prior']['f1']:.3f} (prior) -> {final['scores']['refined']['f1']:.3f} "
                 "(refined)")
    if "labels" in final:
        n, m = right_counts(log)["refined"]
        score += f"; {n} of {m} objects right"
    if "detection" in final:
        d = final["detection"]
        score += (f"; {d['segments']} segments for {d['objects']} objects, {len(d['phantoms'])} phantom(s), "
                  f"F1 with phantoms counted {d['f1']:.3f}")
    print(f"{len(log.moves)} moves{score}", file=sys.stderr)
    return f"wrote {out}"


_OVERWRITE = Argument(("--overwrite",), {"action": "store_true", "help": "write into out_dir even if not empty"})

COMMAND = Command(
    description="Run one active episode: a scene rendered on demand, a dataset scene file or a recording folder "
                "(source=...), one policy (episode.policy=...), GR on or off (episode.refinement=...). Prints each "
                "move (segments, prior -> refined labels, rho, chosen view, module times) and writes <out_dir>: "
                "config.yaml, episode.json, report.md, curves.png (and moves/*.png with pictures=true).",
    schema=RunConfig, run=_run, default_config="run", example="episode.policy=random seed=3 start=17",
    arguments=(_OVERWRITE,),
)

DEMO = Command(
    description="The main job on the embedded default: built-in objects, the shipped weights, one cluttered "
                "scene rendered on the CPU, VisOcclHist with GR. Prints each move and writes <out_dir> "
                "(runs/demo): the per-object table, the F1 curve, a picture per move.",
    schema=RunConfig, run=_run, default_config="demo", example="seed=4 episode.moves=5",
    arguments=(_OVERWRITE,),
)

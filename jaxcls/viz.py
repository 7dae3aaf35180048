"""Figures (matplotlib, headless, no pyplot state): scenes and depth frames, training curves, confusion
matrices. Figures only: the commands and training decide what to draw and where it goes."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from matplotlib import colormaps
from matplotlib.colors import ListedColormap
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from matplotlib.ticker import MaxNLocator

if TYPE_CHECKING:
    from jaxcls.world.scenes import Scene


def class_colours(classes: Sequence[str]) -> dict[str, tuple[float, float, float, float]]:
    """One colour per class name (sorted), from tab10 up to 10 classes, tab20 up to 20, then a hue wheel."""
    names = sorted(set(classes))
    if len(names) <= 10:
        colours = colormaps["tab10"].colors
    elif len(names) <= 20:
        colours = colormaps["tab20"].colors
    else:
        colours = [colormaps["hsv"](i / len(names)) for i in range(len(names))]
    return {name: (*colours[i][:3], 1.0) for i, name in enumerate(names)}


def plot_scene(scene: Scene, T_wc: np.ndarray, views: Sequence[int], depth: np.ndarray, object_id: np.ndarray,
               noisy: bool = False) -> Figure:
    """Depth and object ids of ``views`` (rows of ``depth: [K, H, W]`` m, ``object_id: [K, H, W]``, -1 =
    table) beside the view hemisphere ``T_wc: [V, 4, 4]``. Objects are coloured by class (legend); any
    number of objects. ``noisy``: the depth went through the sensor model (said in the titles)."""
    k = len(views)
    figure = Figure(figsize=(3.2 * k + 5, 5.5))
    grid = figure.add_gridspec(2, k + 2)
    colours = class_colours([o.class_name for o in scene.objects])
    per_object = ListedColormap([colours[o.class_name] for o in scene.objects] or [(0, 0, 0, 1)])
    kind = "sensor depth" if noisy else "depth"
    for col, view in enumerate(views):
        ax = figure.add_subplot(grid[0, col])
        shown = np.where(depth[col] > 0, depth[col], np.nan)
        image = ax.imshow(shown, cmap="viridis")
        ax.set_title(f"view {view}: {kind} (m)", fontsize=9)
        ax.axis("off")
        figure.colorbar(image, ax=ax, fraction=0.035)
        ax = figure.add_subplot(grid[1, col])
        ax.imshow(np.ma.masked_less(object_id[col], 0), cmap=per_object, vmin=-0.5,
                  vmax=max(scene.num_objects, 1) - 0.5, interpolation="nearest")
        ax.set_title(f"view {view}: objects", fontsize=9)
        ax.axis("off")
    ax = figure.add_subplot(grid[:, k:], projection="3d")
    eyes = T_wc[:, :3, 3]
    ax.scatter(*eyes.T, s=8, c="tab:blue", label="viewpoints")
    ax.scatter(*eyes[list(views)].T, s=40, c="tab:red", label="shown")
    # Objects as markers coloured by class, o a target, x clutter: no names drawn at the table's centre
    # (they sat on top of each other there); the legend names the classes and the two markers.
    for obj in scene.objects:
        ax.scatter(obj.position[0], obj.position[1], scene.table_height, s=30, color=colours[obj.class_name],
                   marker="o" if obj.target else "x")
    ax.set_box_aspect((1, 1, 0.5))
    _label_metres(ax)
    clutter = sum(not o.target for o in scene.objects)
    ax.set_title(f"{len(T_wc)} viewpoints, {scene.num_objects} objects"
                 + (f" ({clutter} clutter)" if clutter else ""), fontsize=9)
    roles = [Line2D([], [], ls="", marker="o", color="k", label="target object")]
    if clutter:
        roles.append(Line2D([], [], ls="", marker="x", color="k", label="clutter object (not scored)"))
    handles = [Patch(color=c, label=name) for name, c in colours.items()]
    ax.legend(handles=[*ax.get_legend_handles_labels()[0], *roles, *handles], fontsize=7, loc="upper left")
    figure.tight_layout()
    return figure


def _label_metres(ax) -> None:
    """World axes of a 3-D panel labelled with their units."""
    ax.set_xlabel("x (m)", fontsize=7, labelpad=-2)
    ax.set_ylabel("y (m)", fontsize=7, labelpad=-2)
    ax.set_zlabel("z (m)", fontsize=7, labelpad=-5)
    ax.tick_params(labelsize=6, pad=0)


def training_curve(history: list[dict]) -> Figure:
    """Loss and accuracies (train, and held-out per source) against the epoch, from ``metrics.json``'s history."""
    figure = Figure(figsize=(10, 4))
    epochs = [h["epoch"] for h in history]
    ax = figure.add_subplot(1, 2, 1)
    ax.plot(epochs, [h["loss"] for h in history], color="k", lw=1, label="training loss")
    for source in (history[0].get("test_loss", {}) if history else {}):  # runs before 2026-11-25 have none
        ax.plot(epochs, [h["test_loss"][source] for h in history], lw=1, label=f"held-out NLL, {source}")
    ax.set(xlabel="epoch", ylabel="loss (nats)", yscale="log")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.legend(fontsize=7, loc="lower left")
    if history and "learning_rate" in history[0]:
        rate = ax.twinx()
        rate.plot(epochs, [h["learning_rate"] for h in history], color="0.6", ls="--", lw=1)
        rate.set(ylabel="learning rate (dashed)", yscale="log")
    ax = figure.add_subplot(1, 2, 2)
    ax.plot(epochs, [h["train_accuracy"] for h in history], label="train", color="k", lw=1)
    for source in (history[0]["test_accuracy"] if history else {}):
        ax.plot(epochs, [h["test_accuracy"][source] for h in history], label=f"held-out, {source}")
    ax.set(xlabel="epoch", ylabel="accuracy", ylim=(0, 1))
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.legend(fontsize=8)
    figure.tight_layout()
    return figure


def _held_out_f1(ax, step: str, entries: list[dict], suffix: str) -> None:
    """The held-out F1 of the learned policy and of the hand-made ones evaluated beside it, against ``step``."""
    x = [h[step] for h in entries]
    for key, label, style in (("f1_learned", "learned (GR)", {"color": "C0", "marker": "o"}),
                              ("f1_vis_occl_hist", "VisOcclHistGR", {"color": "0.4", "ls": "--"}),
                              ("f1_info_gain", "InfoGainGR", {"color": "C2", "ls": ":"})):
        if entries and all(key in h for h in entries):  # (runs before InfoGainGR was evaluated have none)
            ax.plot(x, [h[key] for h in entries], label=label + suffix, **style)


def policy_curve(history: list[dict]) -> Figure:
    """A learned view policy's training (``jaxcls train-policy``'s ``metrics.json`` history): against the imitation
    round, the loss and the regret (true F1 given up at a decision; on the validation scenes too, where the fit left
    some out) and the held-out macro F1 of the learned policy and of the hand-made ones evaluated beside it; where
    the fit left scenes out, each round's validation loss against the epoch, the epoch kept marked; against the PPO
    update (where there are any), the rollouts' mean F1 after the last move and the held-out F1 where it was
    evaluated."""
    rounds = [h for h in history if "round" in h]
    updates = [h for h in history if "update" in h]
    imitation = bool(rounds) or not updates  # (PPO alone, from a trained policy: its panel only)
    epochs = [h for h in rounds if h.get("val_losses")]  # (runs with validation)
    panels = 2 * imitation + bool(epochs) + bool(updates)
    figure = Figure(figsize=(5 * panels, 4))
    if imitation:
        ax = figure.add_subplot(1, panels, 1)
        ax.plot([h["round"] for h in rounds], [h["loss"] for h in rounds], color="k", lw=1, marker="o")
        ax.set(xlabel="round", ylabel="imitation loss (nats, black)")
        ax.set_title("on every decision so far (the round's training data)", fontsize=9)
        regret = ax.twinx()
        regret.plot([h["round"] for h in rounds], [h["regret"] for h in rounds], color="C3", lw=1, marker="s")
        validated = [h for h in rounds if "val_regret" in h]  # (validation: the fit's left-out scenes, dashed)
        regret.plot([h["round"] for h in validated], [h["val_regret"] for h in validated], color="C3", lw=1,
                    ls="--", marker="s", mfc="none")
        regret.set(ylabel="regret: F1 given up (red; dashed: validation)" if validated
                   else "regret: F1 given up a decision (red)")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax = figure.add_subplot(1, panels, 2)
        _held_out_f1(ax, "round", rounds, "")
        ax.set(xlabel="round", ylabel="held-out macro F1 after the last move")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        if rounds:
            ax.legend(fontsize=8)
    if epochs:
        ax = figure.add_subplot(1, panels, 3)
        for i, h in enumerate(epochs):
            losses = h["val_losses"]
            ax.plot(range(1, len(losses) + 1), losses, color=f"C{i % 10}", lw=1, label=f"round {h['round']}")
            if "epoch" in h:  # (early stopping: the epoch whose weights the round kept)
                ax.plot(h["epoch"], losses[h["epoch"] - 1], color=f"C{i % 10}", marker="o")
        ax.set(xlabel="epoch", ylabel="validation loss (nats; dot: epoch kept)")
        ax.set_title("the fit's left-out scenes, each round", fontsize=9)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.legend(fontsize=8)
    if updates:
        ax = figure.add_subplot(1, panels, panels)
        rolled = [h for h in updates if "f1_last" in h]  # (update 0: the starting policy, evaluated only)
        ax.plot([h["update"] for h in rolled], [h["f1_last"] for h in rolled], color="k", lw=1,
                label="rollouts (sampled), training scenes")
        _held_out_f1(ax, "update", [h for h in updates if "f1_learned" in h], ", held-out")
        ax.set(xlabel="PPO update", ylabel="macro F1 after the last move")
        ax.legend(fontsize=8)
    figure.tight_layout()
    return figure


def confusion(confusions: dict[str, np.ndarray], classes: Sequence[str]) -> Figure:
    """One row-normalised confusion matrix per cloud source (rows: true class, columns: predicted)."""
    figure = Figure(figsize=(4.2 * len(confusions), 4.4))
    for col, (source, counts) in enumerate(confusions.items()):
        ax = figure.add_subplot(1, len(confusions), col + 1)
        rates = counts / np.maximum(counts.sum(axis=1, keepdims=True), 1)
        ax.imshow(rates, cmap="Blues", vmin=0, vmax=1)
        for i, j in np.ndindex(rates.shape):
            ax.text(j, i, f"{rates[i, j]:.2f}".lstrip("0") if rates[i, j] else "", ha="center", va="center",
                    fontsize=6, color="w" if rates[i, j] > 0.5 else "k")
        ax.set_xticks(range(len(classes)), classes, rotation=90, fontsize=7)
        ax.set_yticks(range(len(classes)), classes, fontsize=7)
        ax.set_xlabel("predicted class", fontsize=8)
        ax.set_ylabel("true class", fontsize=8)
        ax.set_title(f"{source}: accuracy {np.trace(counts) / max(counts.sum(), 1):.3f}", fontsize=9)
    figure.tight_layout()
    return figure


def reliability(calibrations: dict) -> Figure:
    """Reliability diagrams, one panel per entry of ``calibrations`` (name -> ``metrics.Calibration``): the
    accuracy of each confidence bin against its mean confidence; the diagonal is perfect calibration."""
    figure = Figure(figsize=(3.4 * max(len(calibrations), 1), 3.6))
    for col, (name, cal) in enumerate(calibrations.items()):
        ax = figure.add_subplot(1, max(len(calibrations), 1), col + 1)
        bins = len(cal.count)
        centres = (np.arange(bins) + 0.5) / bins
        ax.bar(centres, np.nan_to_num(cal.accuracy), width=1 / bins, edgecolor="k", lw=0.5, label="accuracy")
        ax.plot([0, 1], [0, 1], "k--", lw=1, label="calibrated")
        shown = cal.count > 0
        ax.plot(cal.confidence[shown], cal.accuracy[shown], "o", color="tab:red", ms=3, label="bin mean")
        ax.set(xlim=(0, 1), ylim=(0, 1), xlabel="confidence (top-1 probability)", ylabel="accuracy")
        ax.set_title(f"{name}\nECE {cal.ece:.3f}, {int(cal.count.sum())} segments", fontsize=8)
        ax.legend(fontsize=6, loc="upper left")
    figure.tight_layout()
    return figure


_CUBOID_EDGES = [(a, b) for a in range(8) for b in range(a + 1, 8) if bin(a ^ b).count("1") == 1]  # bit corners


def episode_move(title: str, depth: np.ndarray, pixels: np.ndarray, pixel_labels: Sequence[str],
                 cuboids: np.ndarray, cuboid_labels: Sequence[str], points: np.ndarray, point_labels: Sequence[str],
                 viewpoints: np.ndarray, path: Sequence[int], chosen: int, classes: Sequence[str]) -> Figure:
    """One move of an episode in four panels: the depth frame; the segments over it, coloured by refined
    class; the segments and their aligned model cuboids in 3D; the view hemisphere with the path and the
    chosen next view.

    depth: [H, W] m (0 = no return); pixels: [Q, 2] (u, v) of segment points in the frame, pixel_labels: [Q]
    their class names; cuboids: [N, 8, 3] world corners (corner i has bits x, y, z), cuboid_labels: [N];
    points: [P, 3] world segment points, point_labels: [P]; viewpoints: [V, 4, 4] T_wc; path: views fused in
    order; chosen: the next view; classes: every class name (fixes the colours)."""
    colours = class_colours(classes)
    figure = Figure(figsize=(16, 4.4))
    ax = figure.add_subplot(1, 4, 1)
    image = ax.imshow(np.where(depth > 0, depth, np.nan), cmap="viridis")
    ax.set_title("depth (no return: blank)", fontsize=9)
    ax.axis("off")
    figure.colorbar(image, ax=ax, fraction=0.035, pad=0.02).set_label("depth (m)", fontsize=8)
    ax = figure.add_subplot(1, 4, 2)
    ax.imshow(np.where(depth > 0, depth, np.nan), cmap="Greys", alpha=0.5)
    if len(pixels):
        ax.scatter(pixels[:, 0], pixels[:, 1], s=1, c=[colours[c] for c in pixel_labels])
    ax.set_xlim(0, depth.shape[1])
    ax.set_ylim(depth.shape[0], 0)
    ax.set_title("segments by refined class", fontsize=9)
    ax.axis("off")
    ax.legend(handles=[Patch(color=colours[c], label=c) for c in sorted(set(cuboid_labels))], fontsize=7,
              loc="lower right")
    ax = figure.add_subplot(1, 4, 3, projection="3d")
    if len(points):
        ax.scatter(*np.asarray(points).T, s=0.5, c=[colours[c] for c in point_labels])
    for corners, label in zip(cuboids, cuboid_labels, strict=True):
        for a, b in _CUBOID_EDGES:
            ax.plot(*np.stack([corners[a], corners[b]]).T, color=colours[label], lw=1)
    ax.set_box_aspect((1, 1, 0.6))
    _label_metres(ax)
    ax.set_title("segments and aligned models (cuboids), world frame", fontsize=9)
    ax = figure.add_subplot(1, 4, 4, projection="3d")
    eyes = np.asarray(viewpoints)[:, :3, 3]
    ax.scatter(*eyes.T, s=5, c="lightgrey", label="viewpoints")
    ax.plot(*eyes[list(path)].T, "-o", color="tab:blue", ms=3, lw=1, label="visited")
    ax.scatter(*eyes[path[-1]], s=40, c="tab:blue", label="current view")
    ax.scatter(*eyes[chosen], s=60, c="tab:red", marker="*", label="next")
    ax.set_box_aspect((1, 1, 0.5))
    _label_metres(ax)
    ax.legend(fontsize=7, loc="upper left")
    ax.set_title("views", fontsize=9)
    figure.suptitle(title, fontsize=10)
    figure.tight_layout()
    return figure


def score_curves(panels: dict[str, dict[str, tuple[Sequence[float], Sequence[float], Sequence[float]]]],
                 ylabel: str = "F1") -> Figure:
    """Scores over moves with confidence bands, one panel per key of ``panels`` (e.g. per classifier): each
    maps a row's label to (values, lows, highs), one per move (moves from 1). A row of one value (a single
    view, or every view fused) is drawn as a horizontal line across the panel with its band."""
    figure = Figure(figsize=(5.5 * len(panels), 5.6))
    longest = max((len(v[0]) for rows in panels.values() for v in rows.values()), default=1)
    colours = colormaps["tab20"].colors
    for p, (title, rows) in enumerate(panels.items()):
        ax = figure.add_subplot(1, len(panels), p + 1)
        for i, (label, (values, lows, highs)) in enumerate(rows.items()):
            colour = colours[i % len(colours)]
            style = "--" if "GR" not in label else "-"
            if len(values) == 1:
                x = np.array([1, longest])
                values, lows, highs = (np.repeat(v, 2) for v in (values, lows, highs))
                style = ":"
            else:
                x = np.arange(1, len(values) + 1)
            ax.plot(x, values, style, color=colour, label=label, lw=1.5)
            ax.fill_between(x, lows, highs, color=colour, alpha=0.12, lw=0)
        ax.set_title(title)
        ax.set_xlabel("moves (views fused)")
        ax.set_ylabel(ylabel)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6.5, ncol=3, loc="upper center", bbox_to_anchor=(0.5, -0.14), frameon=False)
    figure.tight_layout()
    return figure


# Wide and solid, then narrow, dashed and hollow on top of it: a curve equal to the one before stays visible.
_CURVE_STYLES = [dict(ls="-", marker="o", ms=7, lw=3, alpha=0.6), dict(ls="--", marker="s", ms=4, lw=1.5, mfc="none"),
                 dict(ls="-", marker="^", ms=7, lw=3, alpha=0.6), dict(ls="--", marker="D", ms=4, lw=1.5, mfc="none")]


def episode_curves(curves: dict[str, Sequence[float]], ylabel: str = "score") -> Figure:
    """Scores over moves: ``curves`` maps a label ("refined F1", ...) to one value per move (moves from 1).

    Each curve has its own line style and marker, wide under narrow, so that curves with the same values
    stay visible one over the other; their labels say so ("F1 prior (= F1 refined)"). The legend sits
    beside the axes, never over a curve."""
    figure = Figure(figsize=(6.8, 3.5))
    ax = figure.add_subplot(1, 1, 1)
    drawn: list[tuple[str, np.ndarray]] = []
    for i, (label, values) in enumerate(curves.items()):
        values = np.asarray(values, float)
        same = [other for other, v in drawn if v.shape == values.shape and np.allclose(v, values, equal_nan=True)]
        drawn.append((label, values))
        if same:
            label = f"{label} (= {same[0]})"
        ax.plot(np.arange(1, len(values) + 1), values, label=label, **_CURVE_STYLES[i % len(_CURVE_STYLES)])
    ax.set_xlabel("moves (views fused)")
    ax.set_ylabel(ylabel)
    ax.set_ylim(0, 1.05)
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0, frameon=False)
    figure.tight_layout()
    return figure


def save(figure: Figure, path: str | Path, dpi: int = 80) -> Path:
    """Write ``figure`` as a PNG atomically."""
    from jaxcls import io

    with io.atomic_write(path) as f:
        figure.savefig(f, dpi=dpi, format="png")
    return Path(path)

"""Training scalars as TensorBoard event files, beside a run's ``metrics.json`` and curve PNGs.

Why TensorBoard's format: it is what PyTorch, Flax (``flax.metrics.tensorboard``), CLU, PureJaxRL's and
big_vision's users already open (``tensorboard --logdir runs``), it is read offline by TensorBoard itself,
``tbparse`` and pandas, and weights-and-biases and MLflow import it; it needs no server and no account
(wandb offline needs its client to sync; MLflow a tracking store). Written with ``tensorboardX`` (pure Python,
no TensorFlow or PyTorch).

One event is written per epoch (``step`` = the epoch, from 1); nested records become slash-separated tags
(``test_accuracy/view``). A resumed run starts its writer with ``purge_step``: TensorBoard (and its
``EventAccumulator``) drops what an interrupted run logged past the epoch the run resumes from, so each epoch
is shown once, with the values of the run that kept it.

    log = ScalarLog(run_dir / "tensorboard", resumed_at=start)
    log.write(epoch, {"loss": 0.4, "test_accuracy": {"view": 0.8}})
    log.close()
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any


def scalars(record: Mapping[str, Any], prefix: str = "") -> dict[str, float]:
    """The finite numbers of ``record`` (nested mappings flattened to ``a/b`` tags; booleans, strings, None,
    lists and non-finite values left out)."""
    out: dict[str, float] = {}
    for name, value in record.items():
        tag = f"{prefix}{name}"
        if isinstance(value, Mapping):
            out.update(scalars(value, f"{tag}/"))
        elif isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value):
            out[tag] = float(value)
    return out


def read_scalars(folder: str | Path) -> dict[str, dict[int, float]]:
    """{tag: {step: value}} of the event files in ``folder`` as TensorBoard loads them (its
    ``EventAccumulator``: a resumed run's purged steps left out), e.g. to compare runs in a notebook. Needs the
    ``tensorboard`` package (``pip install tensorboard``; a test dependency)."""
    try:
        from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
    except ImportError as e:
        raise ImportError("read_scalars: reading event files needs TensorBoard (pip install tensorboard)") from e
    if not Path(folder).is_dir():
        raise FileNotFoundError(f"read_scalars: {folder} is not a folder of event files")
    events = EventAccumulator(str(folder), size_guidance={"scalars": 0})  # (0: keep every event)
    events.Reload()
    return {tag: {e.step: e.value for e in events.Scalars(tag)} for tag in events.Tags()["scalars"]}


class ScalarLog:
    """A run's TensorBoard event files in ``folder`` (created). ``resumed_at``: the last epoch the run had kept
    (0: a new run); later events of an earlier writer are purged on reading."""

    def __init__(self, folder: str | Path, resumed_at: int = 0) -> None:
        try:
            from tensorboardX import SummaryWriter
        except ImportError as e:
            raise ImportError("the training log (tensorboard: true) needs tensorboardX, a dependency of jaxcls "
                              "(pip install tensorboardX), or set tensorboard=false") from e

        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        # (a file of its own per writer, named to sort after the earlier ones even within one second: the event
        # files are named by the second they were opened in, and one opened again would be written over)
        self._writer = SummaryWriter(str(self.folder), purge_step=resumed_at + 1 if resumed_at else None,
                                     filename_suffix=f".{time.time_ns()}")

    def write(self, step: int, record: Mapping[str, Any]) -> None:
        """Every scalar of ``record`` at ``step``, flushed to disk (an interrupted run keeps what it logged)."""
        for tag, value in scalars(record).items():
            self._writer.add_scalar(tag, value, step)
        self._writer.flush()

    def close(self) -> None:
        self._writer.close()

    def __enter__(self) -> ScalarLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


__all__ = ["ScalarLog", "read_scalars", "scalars"]

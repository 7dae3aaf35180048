"""Training logs for TensorBoard (``jaxcls.learn.logs``), read back by TensorBoard's own reader."""

from __future__ import annotations

import sys

import pytest

from jaxcls.learn.logs import ScalarLog, read_scalars, scalars


def test_records_flatten_to_tags_of_finite_numbers():
    record = {"loss": 0.5, "epoch_seconds": 3, "test_accuracy": {"view": 0.8, "full": None}, "note": "x",
              "diverged": False, "rate": float("nan"), "per_class": [0.1, 0.2]}
    assert scalars(record) == {"loss": 0.5, "epoch_seconds": 3.0, "test_accuracy/view": 0.8}


def test_a_resumed_log_shows_each_step_once_with_the_kept_values(tmp_path):
    with ScalarLog(tmp_path) as log:  # a run that logged epochs 1-3, then stopped before keeping epoch 3
        for step in (1, 2, 3):
            log.write(step, {"loss": 1.0 / step, "test": {"acc": 0.1 * step}})
    with ScalarLog(tmp_path, resumed_at=2) as log:  # resumed from its checkpoint of epoch 2
        for step in (3, 4):
            log.write(step, {"loss": 10.0 + step, "test": {"acc": 0.5}})
    got = read_scalars(tmp_path)
    assert set(got) == {"loss", "test/acc"}
    assert got["loss"] == pytest.approx({1: 1.0, 2: 0.5, 3: 13.0, 4: 14.0})
    assert got["test/acc"] == pytest.approx({1: 0.1, 2: 0.2, 3: 0.5, 4: 0.5})
    with pytest.raises(FileNotFoundError, match="not a folder"):
        read_scalars(tmp_path / "missing")


def test_a_missing_tensorboardx_names_the_setting(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "tensorboardX", None)  # (an import of it now raises ImportError)
    with pytest.raises(ImportError, match="tensorboard=false"):
        ScalarLog(tmp_path)

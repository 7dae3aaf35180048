"""The persistent compilation cache (``jaxcls.compile_cache``): a second process loads what the first compiled;
``JAXCLS_CACHE_DIR=off`` turns it off; a folder that cannot be written leaves it off with a warning."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from jaxcls import compile_cache

ROOT = Path(__file__).resolve().parents[1]

# A program that compiles in well under a second: written anyway (min_compile_seconds=0); prints the cache's
# hits and misses as JAX's monitoring events count them.
PROGRAM = """
import jax, jax.numpy as jnp
from jaxcls import compile_cache
events = []
jax.monitoring.register_event_listener(lambda name, **kw: events.append(name))
print("folder", compile_cache.enable(min_compile_seconds=0.0))
f = jax.jit(lambda x: jnp.sin(x) @ x + 1.0)
f(jnp.ones((8, 8))).block_until_ready()
print("hits", sum("cache_hits" in e for e in events), "misses", sum("cache_misses" in e for e in events))
"""


def _run(env: dict[str, str]) -> dict[str, str]:
    out = subprocess.run([sys.executable, "-c", PROGRAM], capture_output=True, text=True, cwd=ROOT,
                         env={**os.environ, "JAX_PLATFORMS": "cpu", **env}, timeout=300)
    assert out.returncode == 0, out.stderr
    words = " ".join(line for line in out.stdout.splitlines() if line.startswith(("folder", "hits"))).split()
    return dict(zip(words[::2], words[1::2], strict=True))


def test_a_second_process_loads_what_the_first_compiled(tmp_path):
    folder = tmp_path / "xla"
    first = _run({compile_cache.ENV: str(folder)})
    assert first["folder"] == str(folder) and int(first["hits"]) == 0 and int(first["misses"]) >= 1
    assert any(folder.iterdir())
    second = _run({compile_cache.ENV: str(folder)})
    assert int(second["hits"]) >= 1 and int(second["misses"]) == 0, second


def test_off_and_unwritable_folders(tmp_path, monkeypatch):
    monkeypatch.setenv(compile_cache.ENV, "off")
    assert compile_cache.cache_folder() is None and compile_cache.enable() is None
    monkeypatch.delenv(compile_cache.ENV)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    assert compile_cache.cache_folder() == tmp_path / "cache" / "jaxcls" / "xla"
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    with pytest.warns(UserWarning, match="compilation cache off"):
        assert compile_cache.enable(blocker / "xla") is None


def test_host_work_is_kept_beside_the_programs_and_rebuilt_when_unreadable(tmp_path, monkeypatch):
    import numpy as np

    from jaxcls.perception import icp
    from jaxcls.world.objects.builtin import builtin_object_set

    monkeypatch.setattr(compile_cache, "_host", None)
    model = builtin_object_set().test[0]
    config = icp.ICPConfig(grid_resolution=16, model_points=256)
    fresh = icp.model_target(model, config)  # cache not enabled: built, nothing written
    monkeypatch.setattr(compile_cache, "_host", tmp_path / "host")
    built = icp.model_target(model, config)
    (entry,) = (tmp_path / "host" / "icp_targets").iterdir()
    def no_tree(points):
        raise AssertionError("built again instead of read back")

    with monkeypatch.context() as m:
        m.setattr(icp, "cKDTree", no_tree)
        loaded = icp.model_target(model, config)  # read back, not built: the same lookups
    for a, b, c in zip((fresh.grid, fresh.neighbours), (built.grid, built.neighbours),
                       (loaded.grid, loaded.neighbours), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
        np.testing.assert_array_equal(np.asarray(a), np.asarray(c))
    calls = []
    assert compile_cache.cached_arrays("icp_targets", b"other", lambda: calls.append(1) or {"x": np.ones(2)})
    assert calls == [1] and len(list((tmp_path / "host" / "icp_targets").iterdir())) == 2  # another key
    entry.write_bytes(b"not an npz")
    again = icp.model_target(model, config)
    np.testing.assert_array_equal(np.asarray(again.grid), np.asarray(fresh.grid))
    with np.load(entry) as repaired:  # rebuilt and replaced
        np.testing.assert_array_equal(repaired["index"].reshape(np.asarray(fresh.grid).shape), np.asarray(fresh.grid))
    monkeypatch.setattr(compile_cache, "_host", None)
    assert compile_cache.cached_arrays("icp_targets", b"other", lambda: {"x": np.zeros(1)})["x"][0] == 0

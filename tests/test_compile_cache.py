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

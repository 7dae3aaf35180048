"""The persistent compilation cache (``jaxcls.compile_cache``): a second process loads what the first compiled;
``JAXCLS_CACHE_DIR=off`` turns it off; a folder that cannot be written leaves it off with a warning."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from flax import struct

from jaxcls import compile_cache

ROOT = Path(__file__).resolve().parents[1]

# A program that compiles in well under a second: written all the same with the default settings (a warm process
# loads a start-up's small programs rather than compiling them again); prints the cache's hits and misses as JAX's
# monitoring events count them.
PROGRAM = """
import jax, jax.numpy as jnp
from jaxcls import compile_cache
events = []
jax.monitoring.register_event_listener(lambda name, **kw: events.append(name))
print("folder", compile_cache.enable())
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


# A program of two nested functions lowered after ``enable``: its operations' locations, as text.
LOCATIONS = """
import jax, jax.numpy as jnp
from jaxcls import compile_cache
compile_cache.enable()

def inner(x):
    return jnp.sin(x) * 2.0

def outer(x):
    return inner(x) + 1.0

print(jax.jit(outer).lower(1.0).as_text(debug_info=True))
"""


@pytest.mark.parametrize("full", [False, True])
def test_operations_carry_one_source_frame_unless_jax_is_told_otherwise(tmp_path, full):
    # One frame: each operation's location is its line alone, no call stack (``callsite``) for a GPU to format
    # into every kernel's annotation at each load; JAX's own variable set keeps the whole traceback.
    env = {**os.environ, "JAX_PLATFORMS": "cpu", compile_cache.ENV: str(tmp_path / "xla")}
    env.pop(compile_cache.FULL_TRACEBACKS_ENV, None)
    if full:
        env[compile_cache.FULL_TRACEBACKS_ENV] = "true"
    done = subprocess.run([sys.executable, "-c", LOCATIONS], capture_output=True, text=True, cwd=ROOT, env=env,
                          timeout=300)
    assert done.returncode == 0, done.stderr
    text = done.stdout
    assert "stablehlo.sine" in text and ("callsite(" in text) == full
    assert '"<string>":7:' in text, text  # inner's line, either way


# A sharded program over a pytree with a static setting, through ``compile_cache.exported`` on two CPU devices:
# prints how many programs it traced besides the cached one's wrapper, and its result.
EXPORTED = """
import warnings
import jax, jax.numpy as jnp
import numpy as np
from flax import struct
from jax.sharding import Mesh, NamedSharding, PartitionSpec
from jaxcls import compile_cache

@struct.dataclass
class Settings:
    scale: jax.Array
    power: int = struct.field(pytree_node=False)

traced = []
jax.monitoring.register_event_duration_secs_listener(
    lambda name, secs, fun_name=None, **kw: traced.append(fun_name) if name.endswith("jaxpr_trace_duration") else None)
compile_cache.enable(min_compile_seconds=0.0)
mesh = Mesh(np.asarray(jax.devices()), ("e",))
split, every = NamedSharding(mesh, PartitionSpec("e")), NamedSharding(mesh, PartitionSpec())

def heavy(settings, x):
    return Settings(scale=jnp.sin(x) ** settings.power * settings.scale, power=settings.power)

args = (jax.device_put(Settings(jnp.float32(2.0), 3), every), jax.device_put(jnp.arange(8.0), split))
before = len(traced)
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    # (with XLA options, as Table 1's program: they go to the compilation, not into the exported program)
    out = compile_cache.exported(jax.jit(heavy), args, "test", {"xla_gpu_autotune_level": 0})(*args)
assert isinstance(out, Settings) and out.power == 3 and out.scale.sharding.is_equivalent_to(split, 1)
# (JAX traces the program read from the cache as one call: its wrapper, "call")
print("traced", len([name for name in traced[before:] if name != "call"]),
      "warned", int(any("cannot read" in str(w.message) for w in caught)),
      "unexported", int(any("not exported" in str(w.message) for w in caught)),
      "result", ",".join(f"{v:.6f}" for v in np.asarray(out.scale)))
"""


def test_a_program_kept_exported_is_compiled_without_tracing(tmp_path):
    env = {**os.environ, "JAX_PLATFORMS": "cpu", "XLA_FLAGS": "--xla_force_host_platform_device_count=2",
           compile_cache.ENV: str(tmp_path / "xla")}

    def run() -> dict[str, str]:
        done = subprocess.run([sys.executable, "-c", EXPORTED], capture_output=True, text=True, cwd=ROOT, env=env,
                              timeout=300)
        assert done.returncode == 0, done.stderr[-3000:]
        words = done.stdout.split()
        return dict(zip(words[::2], words[1::2], strict=True))

    first, second = run(), run()
    assert first["traced"] == "1" and second["traced"] == "0", (first, second)
    assert first["unexported"] == second["unexported"] == "0"
    want = np.sin(np.arange(8.0)) ** 3 * 2.0
    np.testing.assert_allclose([float(v) for v in first["result"].split(",")], want, atol=1e-6)
    assert second["result"] == first["result"]
    (entry,) = (tmp_path / "exported" / "test").iterdir()
    entry.write_bytes(b"damaged")  # read again: traced and kept anew, with a warning
    third = run()
    assert third["traced"] == "1" and third["warned"] == "1" and third["result"] == first["result"]
    assert run()["traced"] == "0"


@struct.dataclass
class Settings:
    """A pytree with a static setting (as an episode's config)."""

    x: object
    moves: int = struct.field(pytree_node=False)


def test_the_key_of_an_exported_program_is_what_tracing_reads(monkeypatch):
    """Shape, dtype, placement and static settings each change the key; values do not; without the cache a
    program is its jitted self."""
    import jax
    import jax.numpy as jnp
    from jax.sharding import NamedSharding, PartitionSpec

    mesh = jax.sharding.Mesh(jax.devices()[:1], ("e",))
    split = NamedSharding(mesh, PartitionSpec("e"))
    x = jax.device_put(jnp.ones((4, 3)), split)
    key = compile_cache.exported_key
    assert key((x,)) == key((x + 1,))
    assert key((x,)) != key((jax.device_put(jnp.ones((4, 2)), split),))
    assert key((x,)) != key((jax.device_put(jnp.ones((4, 3), jnp.int32), split),))
    assert key((x,)) != key((jax.device_put(jnp.ones((4, 3)), NamedSharding(mesh, PartitionSpec())),))
    assert key((Settings(x, 10),)) == key((Settings(x, 10),)) != key((Settings(x, 11),))
    # An array's shape with its sharding (frames not yet rendered) is keyed as the array itself.
    assert key((jax.ShapeDtypeStruct((4, 3), jnp.float32, sharding=split),)) == key((x,))
    with pytest.raises(TypeError, match="JAX arrays"):
        key((np.ones(3),))
    with pytest.raises(TypeError, match="sharding"):
        key((jax.ShapeDtypeStruct((4, 3), jnp.float32),))
    monkeypatch.setattr(compile_cache, "_host", None)
    program = jax.jit(lambda a: a * 2)
    assert compile_cache.exported(program, (x,), "test") is program
    options = {"xla_gpu_autotune_level": 0}  # with XLA options: one jitted program per program and options
    optioned = compile_cache.exported(program, (x,), "test", options)
    assert optioned is compile_cache.jitted(program, dict(options)) is not program
    np.testing.assert_array_equal(optioned(x), program(x))


# Two threads ask for one program while it is made ahead from its arguments' shapes alone (``compile_cache.ahead``);
# prints whether they got that one, how many times it was traced to be kept (``flat``, its wrapper: once), the
# results against the plain jitted program's, and what a failing load gives.
AHEAD = """
import threading, warnings
import jax, jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec
from jaxcls import compile_cache

traced = []
jax.monitoring.register_event_duration_secs_listener(
    lambda name, secs, fun_name=None, **kw: traced.append(fun_name) if name.endswith("jaxpr_trace_duration") else None)
compile_cache.enable(min_compile_seconds=0.0)
mesh = Mesh(np.asarray(jax.devices()), ("e",))
split = NamedSharding(mesh, PartitionSpec("e"))
program = jax.jit(lambda x: jnp.cumsum(jnp.sin(x) * 3.0))
x = jax.device_put(jnp.arange(16.0), split)
shape = jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=split)
ahead = compile_cache.ahead(lambda: compile_cache.exported(program, (shape,), "test"), "the test program")
results = []
threads = [threading.Thread(target=lambda: results.append(compile_cache.exported(program, (x,), "test")))
           for _ in range(2)]
for t in threads:
    t.start()
for t in threads:
    t.join()
loaded = ahead.result()
failed = compile_cache.ahead(lambda: 1 / 0, "a broken program")
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    broken = failed.result()
both = threading.Barrier(2, timeout=20)  # two loads that finish only together: they run at once, not in a queue
pair = [compile_cache.ahead(lambda: both.wait() is not None, f"program {i}") for i in range(2)]
print("same", int(all(r is loaded for r in results)), "traced", traced.count("flat"),
      "equal", int(np.array_equal(np.asarray(loaded(x)), np.asarray(program(x)))),
      "broken", int(broken is None), "warned", int(any("a broken program" in str(w.message) for w in caught)),
      "together", int(all(p.result() for p in pair)))
"""


def test_a_program_loaded_ahead_from_shapes_is_the_one_calls_get(tmp_path):
    """``compile_cache.ahead`` loads an ``exported`` program on a background thread from its arguments' shapes;
    threads asking for it meanwhile wait for that one program (traced once) with the plain program's results;
    a failing load is warned about, not raised; two loads run at once (``AHEAD_THREADS``)."""
    env = {**os.environ, "JAX_PLATFORMS": "cpu", "XLA_FLAGS": "--xla_force_host_platform_device_count=2",
           compile_cache.ENV: str(tmp_path / "xla")}
    done = subprocess.run([sys.executable, "-c", AHEAD], capture_output=True, text=True, cwd=ROOT, env=env,
                          timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    words = done.stdout.split()
    out = dict(zip(words[::2], words[1::2], strict=True))
    assert out == {"same": "1", "traced": "1", "equal": "1", "broken": "1", "warned": "1", "together": "1"}, out


def test_a_program_that_fails_to_compile_is_not_kept(tmp_path, monkeypatch):
    """A compilation that fails (e.g. out of memory while loading beside running work) raises and keeps nothing:
    the next call makes the program again; only a program JAX cannot export falls back to plain jit."""
    import jax
    import jax.numpy as jnp

    monkeypatch.setattr(compile_cache, "_host", tmp_path / "host")  # (on, without JAX's own cache)
    compiled, failures = compile_cache._compiled, []

    def failing_once(*args, **kwargs):
        if not failures:
            failures.append(1)
            raise RuntimeError("RESOURCE_EXHAUSTED: out of memory")
        return compiled(*args, **kwargs)

    monkeypatch.setattr(compile_cache, "_compiled", failing_once)
    program = jax.jit(lambda a: jnp.cos(a) * 3.0)
    x = jnp.arange(5.0)
    with pytest.raises(RuntimeError, match="out of memory"):
        compile_cache.exported(program, (x,), "test_failing")
    made = compile_cache.exported(program, (x,), "test_failing")
    assert made is not program and made is compile_cache.exported(program, (x,), "test_failing")
    np.testing.assert_allclose(np.asarray(made(x)), np.cos(np.arange(5.0)) * 3.0, rtol=1e-6)


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


def test_a_procedural_object_set_is_kept_and_read_back_the_same(tmp_path, monkeypatch):
    """``kept_on_disk``: a procedural set comes back from the host cache with the same names, classes, split, mesh
    vertices and faces and surface samples as built; a second process-like call reads it without building; with
    the cache off it is built every time; the builtin set goes through it."""
    import numpy as np

    from jaxcls.world.objects import builtin
    from jaxcls.world.objects.model import ObjectSet, kept_on_disk

    def build() -> ObjectSet:
        made = [builtin._builtin_model(c, split, 0, 7, 64, f"{c}_{split}") for c in ("bowl", "mug") for split in (0, 1)]
        return ObjectSet("two", ("bowl", "mug"), (made[0], made[2]), (made[1], made[3]))

    def never() -> ObjectSet:
        raise AssertionError("built again instead of read back")

    original = build()
    monkeypatch.setattr(compile_cache, "_host", tmp_path / "host")
    written = kept_on_disk("test_set", (7,), build)
    read = kept_on_disk("test_set", (7,), never)
    for kept in (written, read):
        assert (kept.name, kept.classes) == (original.name, original.classes)
        for split in ("train", "test"):
            for a, b in zip(getattr(original, split), getattr(kept, split), strict=True):
                assert (a.name, a.class_name) == (b.name, b.class_name)
                np.testing.assert_array_equal(np.asarray(a.mesh.vertices), np.asarray(b.mesh.vertices))
                np.testing.assert_array_equal(np.asarray(a.mesh.faces), np.asarray(b.mesh.faces))
                np.testing.assert_array_equal(a.surface_points, b.surface_points)
                np.testing.assert_array_equal(a.surface_normals, b.surface_normals)
    with pytest.raises(AssertionError, match="built again"):
        kept_on_disk("test_set", (8,), never)  # (other arguments: another entry)
    builtin._builtin_cached.cache_clear()
    try:
        small = builtin.builtin_object_set(seed=5, train_per_class=1, test_per_class=0, surface_samples=32)
        assert any((tmp_path / "host" / "object_sets" / "builtin").iterdir())
        builtin._builtin_cached.cache_clear()  # (as a new process: read back, not built)
        monkeypatch.setattr(builtin, "_builtin_model", lambda *args: never())
        again = builtin.builtin_object_set(seed=5, train_per_class=1, test_per_class=0, surface_samples=32)
        assert [m.name for m in again.train] == [m.name for m in small.train] and len(again.train) == 8
        builtin._builtin_cached.cache_clear()
        monkeypatch.setattr(compile_cache, "_host", None)
        with pytest.raises(AssertionError, match="built again"):  # (the cache off: built)
            builtin.builtin_object_set(seed=5, train_per_class=1, test_per_class=0, surface_samples=32)
    finally:
        builtin._builtin_cached.cache_clear()

"""A process stays under the kernel's memory-map limit (``jaxcls.xla_flags``): importing jaxcls sets the XLA
flags (a user's own flag kept), installs the guard once JAX is imported, and a loop that compiles many
distinct programs, each kept alive, holds a bounded number of maps."""

from __future__ import annotations

import gc
import os
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxcls import xla_flags

linux_only = pytest.mark.skipif(not xla_flags.map_limit(), reason="no /proc/sys/vm/max_map_count (not Linux)")
ROOT = Path(__file__).resolve().parents[1]


def test_flags_are_appended_and_a_users_own_kept():
    assert xla_flags.with_flags("") == " ".join(f"--{k}={v}" for k, v in xla_flags.FLAGS.items())
    mine = "--xla_force_host_platform_device_count=4 --xla_cpu_use_fusion_emitters=true"
    merged = xla_flags.with_flags(mine)
    assert merged.startswith(mine) and merged.count("xla_cpu_use_fusion_emitters") == 1
    assert f"--xla_cpu_parallel_codegen_split_count={xla_flags.SPLIT_COUNT}" in merged
    assert xla_flags.with_flags(merged) == merged
    if os.environ.get(xla_flags.ENV, "").lower() not in xla_flags.OFF and xla_flags.jaxlib_checked():
        assert xla_flags.with_flags(os.environ["XLA_FLAGS"]) == os.environ["XLA_FLAGS"].strip()


@linux_only
def test_importing_jaxcls_before_jax_installs_the_guard_and_the_flags():
    code = ("import os, sys, jaxcls; from jaxcls import xla_flags as x; assert 'jax' not in sys.modules; "
            "assert not x._installed; import jax.numpy as jnp; assert x._installed; "
            "jnp.ones(3).block_until_ready(); print(os.environ.get('XLA_FLAGS')); print(x.stats.peak > 0)")
    env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", xla_flags.ENV)}
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH")) if p)
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    flags = xla_flags.with_flags("") if xla_flags.jaxlib_checked() else "None"
    assert done.stdout.split("\n")[:2] == [flags, "True"]
    off = subprocess.run([sys.executable, "-c", "import os, jaxcls; print(os.environ.get('XLA_FLAGS'))"],
                         env={**env, "XLA_FLAGS": "--xla_cpu_use_fusion_emitters=true", xla_flags.ENV: "off"},
                         capture_output=True, text=True, timeout=120)
    assert off.stdout.strip() == "--xla_cpu_use_fusion_emitters=true", off.stderr


def _program(i: int):
    """A small program of the kind the project compiles (sort, cumulative sum, scatter, product, gather):
    a few tens of kernels, a few tens of memory maps."""

    def program(points, index):
        d = points - points.mean(0) * (1.0 + 1e-3 * i)
        n = jnp.sqrt((d * d).sum(1) + 1e-12)
        ranked = jnp.cumsum(jnp.sort(n)) / (n.sum() + 1.0)
        grid = jnp.zeros((16, 16)).at[index % 16, (index // 16) % 16].add(n)
        mixed = jnp.tanh(grid @ grid.T * (1e-3 * (i + 1)))
        return ranked[-1] + mixed[index % 16].sum() + i

    return jax.jit(program)


@linux_only
def test_many_distinct_programs_keep_the_map_count_bounded(monkeypatch):
    """30 distinct programs (~40 maps each), each kept alive (its jitted function in a list), with the
    guard's budget set 300 maps above what the process holds without programs: the programs would need
    several budgets; the guard frees them before compilations, so the count never goes past the budget by
    more than one program, and every program (freed or not) still computes its value (compiled again)."""
    key = jax.random.PRNGKey(0)
    points = jax.random.normal(key, (512, 3))
    index = jax.random.randint(key, (512,), 0, 256)
    jax.clear_caches()  # the budget from what this process holds without programs (as after a free)
    gc.collect()
    _program(-1)(points, index).block_until_ready()  # JAX's own first-use programs out of the count
    budget = xla_flags.count_maps() + 300
    monkeypatch.setattr(xla_flags, "GUARD_SHARE", budget / xla_flags.map_limit())
    frees = xla_flags.stats.frees
    kept, values, grown, counts = [], [], [], []
    for i in range(30):
        f = _program(i)
        kept.append(f)
        before = xla_flags.count_maps()
        values.append(float(f(points, index)))
        counts.append(xla_flags.count_maps())
        grown.append(max(0, counts[-1] - before))
    assert sum(grown) > 3 * 300  # without freeing, the loop would hold several budgets' worth of maps
    assert xla_flags.stats.frees - frees >= 2
    assert max(counts) <= budget + max(grown) + 50  # one program's maps past the budget at most
    again = [float(f(points, index)) for f in kept[:5]]  # freed programs compile again, same values
    np.testing.assert_allclose(again, values[:5], rtol=1e-6)

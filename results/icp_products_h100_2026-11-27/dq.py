"""depth_fn (a depth-only context where the model has no flexes) against render(T).depth (depth and
segmentation) on scene 3: equal frames, and each one's time for 64 frames."""

import json
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxcls.world import WorldConfig, make_world
from jaxcls.world.scenes import Scene

with np.load(sys.argv[1]) as f:
    T_wc = np.asarray(f["T_wc"], np.float32)
    scene = Scene.from_dict(json.loads(str(f["scene_json"])), source=sys.argv[1])
world = make_world(WorldConfig(backend="warp"), scene=scene)
B = 64
T = jnp.asarray(T_wc[:B])
a = np.asarray(world.renderer.render(T).depth)
fn = jax.jit(world.renderer.depth_fn(B))
b = np.asarray(fn(T))
print("depth_fn vs render: shape", a.shape, b.shape, "identical:", np.array_equal(a, b),
      "max abs diff", float(np.abs(a - b).max()), "returns", int((a > 0).sum()), int((b > 0).sum()))
for name, call in (("render", lambda: world.renderer.render(T).depth), ("depth_fn", lambda: fn(T))):
    call().block_until_ready()
    times = []
    for _ in range(10):
        t0 = time.perf_counter()
        call().block_until_ready()
        times.append(time.perf_counter() - t0)
    print(f"{name}: median {np.median(times) * 1e3:.2f} ms for {B} frames")

"""Runs experiments/table1.py with JAX's compile log on, each line stamped (s since start, thread)."""
import logging
import runpy
import sys
import time

T0 = time.perf_counter()


class Stamp(logging.Formatter):
    def format(self, record):
        return f"{time.perf_counter() - T0:7.3f} {record.threadName[:14]:14s} {record.getMessage()[:300]}"


h = logging.StreamHandler(sys.stderr)
h.setFormatter(Stamp())
logging.getLogger("jax").addHandler(h)
logging.getLogger("jax").setLevel(logging.DEBUG)
logging.getLogger("jax").propagate = False
import jax  # noqa: E402

jax.config.update("jax_log_compiles", True)
sys.argv = ["experiments/table1.py", *sys.argv[1:]]
runpy.run_path("experiments/table1.py", run_name="__main__")

"""The ``jaxcls`` command: ``jaxcls <subcommand> [--config FILE] [key.sub=value ...]``.

Each subcommand is a typed entry of ``COMMANDS``: a one-line summary and the loader of its module's
``Command`` (schema, run function, arguments; ``jaxcls.commands``). Only the chosen command's module is
imported, so ``jaxcls train`` needs no MuJoCo and ``jaxcls --help`` starts fast.

Ctrl-C (``CtrlC``) ends a command at any moment, its first second included, with exit status 130 and
``jaxcls <command>: interrupted`` (plus ``: run the same command again to resume`` for a resumable
command). Python delivers SIGINT as a KeyboardInterrupt wherever the main thread happens to be, and a
KeyboardInterrupt raised inside a garbage-collector callback (JAX's ``_xla_gc_callback``) or an ``except``
that catches everything is lost: the command then ran to its end with exit status 0. The process's own
SIGINT handler therefore does not trust one delivery: a watcher thread, woken by the signal itself
(``signal.set_wakeup_fd``), delivers it again until ``main`` has caught it, and when the main thread is held
in native code (an XLA compilation, the ray caster) for longer than ``CtrlC.GRACE_S`` seconds, or Ctrl-C is
pressed twice, it ends the process itself. A Ctrl-C that comes while a module is being
imported (the first seconds: JAX, MuJoCo, Matplotlib) ends the process at once: a KeyboardInterrupt raised
inside jaxlib's initialisation crashed it (exit status 139). Every result is written atomically
(``jaxcls.io``), so ending there leaves no half-written file. An interrupted process leaves with
``os._exit``, without the interpreter's shutdown (XLA's threads may still run). Python's own start-up, the
first ~0.1 s before ``main`` runs, keeps Python's default behaviour.
"""

from __future__ import annotations

import _thread
import argparse
import dataclasses
import gc
import os
import select
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

from jaxcls import __version__, allocator, compile_cache
from jaxcls.commands import Command

# Nothing heavier at the top (OmegaConf, JAX, MuJoCo load with the command): ``main`` takes Ctrl-C over at
# once, and ``jaxcls --help`` starts fast.


def _show() -> Command:
    from jaxcls.commands import show

    return show.COMMAND


def _dataset() -> Command:
    from jaxcls.commands import dataset

    return dataset.COMMAND


def _train() -> Command:
    from jaxcls.commands import train

    return train.COMMAND


def _train_policy() -> Command:
    from jaxcls.commands import policy

    return policy.COMMAND


def _export() -> Command:
    from jaxcls.commands import export

    return export.COMMAND


def _view() -> Command:
    from jaxcls.commands import view

    return view.COMMAND


def _run_command() -> Command:
    from jaxcls.commands import run

    return run.COMMAND


def _demo() -> Command:
    from jaxcls.commands import run

    return run.DEMO


@dataclasses.dataclass(frozen=True)
class Entry:
    """A subcommand in the registry: its summary for ``jaxcls --help`` and the loader of its ``Command``."""

    summary: str
    load: Callable[[], Command]
    resumable: bool = False  # its Command's (a test checks): known before the module loads, for Ctrl-C's message


COMMANDS: dict[str, Entry] = {
    "demo": Entry("the main job on the built-in default: one cluttered scene, VisOcclHist with GR, a report", _demo),
    "run": Entry("run one active episode (a scene, a dataset file or a recording; one policy)", _run_command),
    "show": Entry("save a PNG of a scene: depth of a few views and the view hemisphere", _show),
    "dataset": Entry("render scenes x all viewpoints to disk (resumable)", _dataset, resumable=True),
    "train": Entry("train the PointNet classifier (resumes an interrupted run)", _train, resumable=True),
    "train-policy": Entry("train the learned view policy by imitation of the oracle (resumable)", _train_policy,
                          resumable=True),
    "export": Entry("write one rendered scene as a recorded sequence (or a dataset in BOP's layout)", _export),
    "view": Entry("open an episode's 3-D recording (episode.rrd) in rerun's viewer, or its web viewer", _view),
}


def _top_parser() -> argparse.ArgumentParser:
    lines = [f"  {name:<12} {entry.summary}" for name, entry in COMMANDS.items()]
    parser = argparse.ArgumentParser(
        prog="jaxcls", formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Active 3D classification of multiple objects in cluttered scenes.\n\ncommands:\n"
                    + "\n".join(lines) + "\n\nRun 'jaxcls <command> --help' for a command's options.")
    parser.add_argument("--version", action="version", version=f"jaxcls {__version__}")
    parser.add_argument("command", choices=list(COMMANDS), metavar="command", help="one of: " + ", ".join(COMMANDS))
    return parser


def command_parser(name: str, command: Command) -> argparse.ArgumentParser:
    """The parser of one subcommand: its own arguments, then ``--config``, ``--print-config`` and overrides."""
    parser = argparse.ArgumentParser(prog=f"jaxcls {name}", description=command.description)
    for argument in command.arguments:
        parser.add_argument(*argument.flags, **argument.options)
    if command.schema is not None:
        default = command.default_config
        parser.add_argument("--config", default=default, help="YAML config: a path or a shipped config name"
                            + (f" (default: {default})" if default else " (default: the built-in defaults)"))
        parser.add_argument("--print-config", action="store_true", help="print the resolved config and exit")
        example = f", e.g. {command.example}" if command.example else ""
        parser.add_argument("overrides", nargs="*", metavar="key=value",
                            help=f"dotted overrides applied after the config file{example}")
    return parser


def load_command_config(name: str, command: Command, path: str | None, overrides: Sequence[str]):
    """The command's config from ``path`` and ``overrides``; a file of one of ``command.reads_world_of``
    (and not of the command's own schema) lends its world only, said on stderr."""
    from jaxcls.config import ConfigError, load_config

    try:
        return load_config(command.schema, path, overrides)
    except ConfigError:
        for other in command.reads_world_of if path else ():
            try:
                load_config(other, path)
            except ConfigError:
                continue
            keys = ", ".join(f.name for f in dataclasses.fields(command.world_schema))
            print(f"jaxcls {name}: {path} is a {other.__name__} file: reading its world only ({keys})",
                  file=sys.stderr)
            return load_config(command.schema, path, overrides, keep_only=command.world_schema)
        raise


SEED_LIMIT = 2**32  # seeds in [0, 2**32): what NumPy's and JAX's generators take alike (32-bit unsigned)


def check_seeds(config: Any, path: str | None, overrides: Sequence[str], prefix: str = "") -> None:
    """Every ``seed`` of ``config`` and its blocks (``seed``, ``objects.seed``, ...) in ``SEED``'s range, or
    a ConfigError naming the dotted key and where it came from (the command line, the file, the defaults):
    a seed out of range failed deep inside NumPy ("expected non-negative integer") or JAX (OverflowError)."""
    from jaxcls.config import Bounds, ConfigError

    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        key = f"{prefix}{f.name}"
        if dataclasses.is_dataclass(value):
            check_seeds(value, path, overrides, f"{key}.")
        elif f.name == "seed" and (why := Bounds(ge=0, lt=SEED_LIMIT).violation(value)) is not None:
            given = any(o.split("=", 1)[0].strip() == key for o in overrides)
            raise ConfigError(f"{'command line' if given else path or 'defaults'}: key '{key}' {why} "
                              "(a seed is a 32-bit unsigned integer)")


def interrupted_message(name: str, resumable: bool) -> str:
    """What an interrupted command prints on stderr."""
    return f"jaxcls {name}: interrupted" + (": run the same command again to resume" if resumable else "")


class CtrlC:
    """SIGINT for a ``jaxcls`` process (see the module docstring): the handler raises KeyboardInterrupt in
    the main thread (not inside a garbage-collector callback, where it would be lost); a watcher thread,
    woken through ``signal.set_wakeup_fd`` even while the main thread runs native code, delivers it again
    every ``RESEND_S`` seconds until ``main`` has caught it (``caught``), and ends the process with
    ``message`` and status 130 after ``GRACE_S`` seconds, or at a second Ctrl-C."""

    RESEND_S = 0.5
    GRACE_S = 3.0

    def __init__(self, message: str):
        self.message = message
        self.caught = False  # main has caught the KeyboardInterrupt (or finished): the watcher stands down
        self.first: float | None = None  # when Ctrl-C was first pressed (monotonic)
        self.presses = 0
        self._resent = 0  # our own deliveries still to be read back from the wakeup pipe
        self._lock = threading.Lock()
        self._exiting = threading.Lock()

    def install(self) -> bool:
        """Take SIGINT over; False (nothing changed) off the main thread, or where SIGINT is ignored (a
        background job started by a non-interactive shell: it is not the terminal's to stop)."""
        if threading.current_thread() is not threading.main_thread():
            return False
        if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
            return False
        read, write = os.pipe()
        os.set_blocking(write, False)
        signal.set_wakeup_fd(write, warn_on_full_buffer=False)
        signal.signal(signal.SIGINT, self._handler)
        threading.Thread(target=self._watch, args=(read,), name="jaxcls-ctrl-c", daemon=True).start()
        return True

    def _handler(self, signum: int, frame: Any) -> None:
        if self.caught:
            return
        where = _interrupted_in(frame)
        if where == "import":
            self.exit()  # raised inside a C extension's initialisation (jaxlib's) it crashed the process
        if where == "gc":
            return  # the exception would be swallowed there: the watcher delivers it again
        raise KeyboardInterrupt

    def _watch(self, fd: int) -> None:
        last_sent = 0.0
        while True:
            ready, _, _ = select.select([fd], [], [], 0.1)
            if ready:
                for byte in os.read(fd, 512):
                    if byte != signal.SIGINT:
                        continue
                    with self._lock:
                        if self._resent:
                            self._resent -= 1
                            continue
                        self.presses += 1
                        if self.first is None:
                            self.first = last_sent = time.monotonic()
            if self.caught or self.first is None:
                continue
            now = time.monotonic()
            if self.presses >= 2 or now - self.first > self.GRACE_S:
                self.exit()
            if now - last_sent >= self.RESEND_S:
                with self._lock:
                    self._resent += 1
                last_sent = now
                _thread.interrupt_main(signal.SIGINT)

    def exit(self) -> None:
        """Say ``message`` on stderr and end the process at once with status 130 (once: a second caller, the
        main thread or the watcher, waits for the first to end the process)."""
        self.caught = True
        if not self._exiting.acquire(blocking=False):
            time.sleep(60)
        try:
            sys.stdout.flush()
        except Exception:  # a flush racing the main thread's own write: what was printed is out already
            pass
        os.write(2, (_fresh_line() + self.message + "\n").encode())
        os._exit(130)


def _fresh_line() -> str:
    """A newline where a progress bar (tqdm's, redrawn in place with a carriage return) holds stderr's current
    line, so that a message after it starts a line of its own; else nothing."""
    tqdm_module = sys.modules.get("tqdm.std")
    return "\n" if tqdm_module is not None and len(getattr(tqdm_module.tqdm, "_instances", ())) else ""


def _interrupted_in(frame: Any) -> str:
    """Where the main thread was when SIGINT came: ``import`` (a module is being imported: a
    KeyboardInterrupt there can break a C extension's initialisation, as jaxlib's did with a segmentation
    fault), ``gc`` (a garbage-collector callback, which swallows exceptions) or ``code`` (anywhere else)."""
    callbacks = {getattr(callback, "__code__", None) for callback in gc.callbacks}
    while frame is not None:
        if frame.f_code.co_filename.startswith("<frozen importlib._bootstrap"):
            return "import"
        if frame.f_code in callbacks:
            return "gc"
        frame = frame.f_back
    return "code"


def _run(name: str, argv: Sequence[str], ctrl_c: CtrlC) -> str:
    from jaxcls.config import to_yaml

    command = COMMANDS[name].load()
    ctrl_c.message = interrupted_message(name, command.resumable)  # the command's own word from here on
    args = command_parser(name, command).parse_args(argv)
    config = None
    if command.schema is not None:
        config = load_command_config(name, command, args.config or None, args.overrides)
        check_seeds(config, args.config or None, args.overrides)
        if args.print_config:
            return to_yaml(config)
    return command.run(config, args)


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``jaxcls argv...``; returns the exit status. Without ``argv`` (the ``jaxcls`` script, ``python -m
    jaxcls.cli``) this is the process's entry: Ctrl-C is taken over (``CtrlC``) and an interrupted run ends
    the process with status 130; with ``argv`` (from Python) SIGINT is left alone and 130 is returned."""
    entry = argv is None
    argv = list(sys.argv[1:] if argv is None else argv)
    top = _top_parser()
    if not argv or argv[0].startswith("-"):
        top.parse_args(argv or ["--help"])  # --help / --version exit here; anything else is an error
        return 2
    name = argv[0]
    if name not in COMMANDS:
        top.parse_args(argv[:1])  # prints the choices and exits with 2
    ctrl_c = CtrlC(interrupted_message(name, COMMANDS[name].resumable))
    if entry:
        ctrl_c.install()
    try:
        allocator.retain_freed_memory()  # a move's buffers reused, not page-faulted back in (jaxcls.allocator)
        compile_cache.enable()  # compiled programs kept on disk for the next run (jaxcls.compile_cache)
        print(_run(name, argv[1:], ctrl_c), flush=True)
        ctrl_c.caught = True  # done: a Ctrl-C from here on is too late to matter
    except KeyboardInterrupt:
        if entry:
            ctrl_c.exit()  # no interpreter shutdown behind an interrupted run (see the module docstring)
        ctrl_c.caught = True
        print(_fresh_line() + ctrl_c.message, file=sys.stderr)
        return 130
    except (ValueError, OSError, RuntimeError) as e:  # bad input (ConfigError is one), files, missing GPU
        ctrl_c.caught = True
        if os.environ.get("JAXCLS_DEBUG"):
            raise
        print(f"jaxcls {name}: error: {e}", file=sys.stderr)  # JAXCLS_DEBUG=1: the traceback
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())

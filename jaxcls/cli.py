"""The ``jaxcls`` command: ``jaxcls <subcommand> [--config FILE] [key.sub=value ...]``.

Each subcommand is a typed entry of ``COMMANDS``: a one-line summary and the loader of its module's
``Command`` (schema, run function, arguments; ``jaxcls.commands``). Only the chosen command's module is
imported, so ``jaxcls train`` needs no MuJoCo and ``jaxcls --help`` starts fast.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
from collections.abc import Callable, Sequence

from jaxcls import __version__, allocator, compile_cache
from jaxcls.commands import Command
from jaxcls.config import ConfigError


def _show() -> Command:
    from jaxcls.commands import show

    return show.COMMAND


def _dataset() -> Command:
    from jaxcls.commands import dataset

    return dataset.COMMAND


def _train() -> Command:
    from jaxcls.commands import train

    return train.COMMAND


def _export() -> Command:
    from jaxcls.commands import export

    return export.COMMAND


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


COMMANDS: dict[str, Entry] = {
    "demo": Entry("the main job on the built-in default: one cluttered scene, VisOcclHist with GR, a report", _demo),
    "run": Entry("run one active episode (a scene, a dataset file or a recording; one policy)", _run_command),
    "show": Entry("save a PNG of a scene: depth of a few views and the view hemisphere", _show),
    "dataset": Entry("render scenes x all viewpoints to disk (resumable)", _dataset),
    "train": Entry("train the PointNet classifier (resumes an interrupted run)", _train),
    "export": Entry("write one rendered scene as a recorded sequence", _export),
}


def _top_parser() -> argparse.ArgumentParser:
    lines = [f"  {name:<9} {entry.summary}" for name, entry in COMMANDS.items()]
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
    from jaxcls.config import load_config

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


def _run(name: str, argv: Sequence[str]) -> str:
    from jaxcls.config import to_yaml

    command = COMMANDS[name].load()
    args = command_parser(name, command).parse_args(argv)
    config = None
    if command.schema is not None:
        config = load_command_config(name, command, args.config or None, args.overrides)
        if args.print_config:
            return to_yaml(config)
    return command.run(config, args)


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    top = _top_parser()
    if not argv or argv[0].startswith("-"):
        top.parse_args(argv or ["--help"])  # --help / --version exit here; anything else is an error
        return 2
    name = argv[0]
    if name not in COMMANDS:
        top.parse_args(argv[:1])  # prints the choices and exits with 2
    allocator.retain_freed_memory()  # a move's buffers reused, not page-faulted back in (jaxcls.allocator)
    compile_cache.enable()  # compiled programs kept on disk for the next run (jaxcls.compile_cache)
    try:
        print(_run(name, argv[1:]))
    except KeyboardInterrupt:
        resumable = COMMANDS[name].load().resumable
        print(f"jaxcls {name}: interrupted" + (": run the same command again to resume" if resumable else ""),
              file=sys.stderr)
        return 130
    except (ConfigError, ValueError, OSError, RuntimeError) as e:  # bad input, files, missing GPU
        if os.environ.get("JAXCLS_DEBUG"):
            raise
        print(f"jaxcls {name}: error: {e}", file=sys.stderr)  # JAXCLS_DEBUG=1: the traceback
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The ``jaxcls`` subcommands, one small module each: a config schema, a run function, its own arguments.

``jaxcls.cli`` maps each subcommand name to its module's ``COMMAND`` and loads only the one that runs
(``train`` needs no MuJoCo; ``show`` needs no orbax). Command bodies live here, not in library modules.
"""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Callable
from typing import Any


@dataclasses.dataclass(frozen=True)
class Argument:
    """One extra command-line argument: ``parser.add_argument(*flags, **options)``."""

    flags: tuple[str, ...]
    options: dict = dataclasses.field(default_factory=dict)


@dataclasses.dataclass(frozen=True)
class Command:
    """A subcommand: what it is for, its config schema (None: it takes no config), what it runs.

    run(config, args) -> the line printed when it succeeds. ``default_config`` names a config shipped in
    ``jaxcls/configs`` (or None: the schema's defaults); ``example`` is a dotted override for its help.
    """

    description: str
    schema: type | None
    run: Callable[[Any, argparse.Namespace], str]
    default_config: str | None = None
    example: str = ""
    arguments: tuple[Argument, ...] = ()
    # A config file that is not this command's but one of ``reads_world_of`` (a dataset config given to
    # ``show``) is read for the keys of ``world_schema`` only.
    reads_world_of: tuple[type, ...] = ()
    world_schema: type | None = None
    resumable: bool = False  # an interrupted run picks up where it stopped when run again

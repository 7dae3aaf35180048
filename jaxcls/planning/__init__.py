"""Where to look next (paper Sec. 3.3), after a move's perception and refinement.

- ``visibility``: pixels of each aligned model cuboid a candidate view would see (Eq. 5), hard and soft.

Planning imports perception and the top-level helpers, never the world, the episode or the commands.
"""

from jaxcls.planning import visibility

__all__ = ["visibility"]

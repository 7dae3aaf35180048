"""Where to look next (paper Sec. 3.3), after a move's perception and refinement.

- ``visibility``: pixels of each aligned model cuboid a candidate view would see (Eq. 5), hard and soft;
- ``information``: volumetric information gain of candidate views on the TSDF (beyond the paper);
- ``nbv``: the candidates of a move, the history weight, the utility and the policies (Eq. 6-8);
- ``learned``: the learned policy's features, network and weights files (beyond the paper).

Planning imports perception and the top-level helpers, never the world, the episode or the commands.
"""

from jaxcls.planning import information, learned, nbv, visibility

__all__ = ["information", "learned", "nbv", "visibility"]

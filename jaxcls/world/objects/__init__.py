"""Object sets: the CAD models that scenes are built from and that classification and ICP compare against.

Every model follows the conventions of docs/ARCHITECTURE.md: metres, z up, resting on the table (min z = 0), with the
centre of its xy bounding box at x = y = 0, so that a scene places a model by a yaw and a table position.

Sources:
- ``builtin_object_set`` (``builtin.py``): eight procedural household classes in the spirit of LINEMOD (no
  download): ``bottle, bowl, box, can, drill, jug, lamp, mug``. Each class is a parametric family built from
  closed trimesh primitives (revolved profiles, boxes, cylinders, swept tubes); each instance draws its
  parameters from the class's ranges with a NumPy ``Generator`` seeded by (seed, class, split, index).
  Two pairs of classes differ *only* by a part that some viewpoints hide, which is what makes the active
  choice of view matter:

  * ``mug`` = a ``can`` body + a handle. The body is drawn by the same function from the same ranges
    (``_CAN_BODY``) as a can, so a mug seen from the side opposite its handle is a can.
  * ``jug`` = a ``bottle`` body + a handle (``_BOTTLE_BODY``), likewise.

  Handles (and the drill's parts) are closed meshes that overlap the body; the mesh is their
  concatenation (each part is watertight with outward winding, so the whole is too, with interior faces).
  Surface samples are taken only where no other part covers the surface, so they lie on the visible
  boundary of the union.
- ``lookalike_object_set`` (``lookalike.py``): nine procedural classes in lookalike groups for the hard
  protocol (issue 35): ``bowl, canister, cup, infuser_cup, lug_bowl, mug, spout_bowl, stein, tube_pan``, a cup
  or a bowl body plus a subset of its family's parts (handle, lid, insert; spout, tube, lug), so that lookalike
  classes differ in one part that some viewing directions hide (the module docstring has the table).
- ``load_folder`` (``loaders.py``): one subfolder per class holding instance meshes (.obj/.ply/.stl).
- ``load_bop`` (``loaders.py``): the BOP layout LINEMOD ships in (``models/obj_000001.ply`` in mm +
  ``models_info.json``).
- ``load_object_set`` / ``ObjectSetConfig`` (``loaders.py``): pick one of the above by name
  (``ProceduralSet``: ``builtin``, ``lookalike``) or folder.

The model types ``ObjectModel`` and ``ObjectSet`` live in ``model.py``; mesh normalisation and surface
sampling, shared by every source, in ``mesh.py``. These modules import only NumPy, SciPy, trimesh and each
other.

Models are shared (the builtin set is cached): treat their meshes as read-only and ``copy()`` before
transforming one.
"""

from jaxcls.world.objects.builtin import _BOTTLE_BODY as _BOTTLE_BODY
from jaxcls.world.objects.builtin import _CAN_BODY as _CAN_BODY
from jaxcls.world.objects.builtin import _JUG_HANDLE as _JUG_HANDLE
from jaxcls.world.objects.builtin import _MUG_HANDLE as _MUG_HANDLE
from jaxcls.world.objects.builtin import BUILTIN_CLASSES, builtin_object_set
from jaxcls.world.objects.builtin import _assemble as _assemble
from jaxcls.world.objects.builtin import _builtin_model as _builtin_model
from jaxcls.world.objects.builtin import _instance_parts as _instance_parts
from jaxcls.world.objects.loaders import (
    MAX_MODEL_EXTENT,
    MIN_MODEL_EXTENT,
    ObjectSetConfig,
    ProceduralSet,
    load_bop,
    load_folder,
    load_object_set,
    models_info,
    object_set_from_config,
)
from jaxcls.world.objects.loaders import _check_models_info as _check_models_info
from jaxcls.world.objects.loaders import _is_bop as _is_bop
from jaxcls.world.objects.loaders import _max_distance as _max_distance
from jaxcls.world.objects.loaders import _split_by_class as _split_by_class
from jaxcls.world.objects.lookalike import LOOKALIKE_CLASSES, lookalike_object_set, lookalike_pairs
from jaxcls.world.objects.mesh import MESH_SUFFIXES, UP_AXES, normalise_mesh
from jaxcls.world.objects.mesh import _read_mesh as _read_mesh
from jaxcls.world.objects.mesh import _rest_offset as _rest_offset
from jaxcls.world.objects.mesh import _sample_faces as _sample_faces
from jaxcls.world.objects.mesh import _sample_rng as _sample_rng
from jaxcls.world.objects.mesh import _surface_samples as _surface_samples
from jaxcls.world.objects.mesh import _up_rotation as _up_rotation
from jaxcls.world.objects.mesh import _winding_numbers as _winding_numbers
from jaxcls.world.objects.model import ObjectModel, ObjectSet

__all__ = [
    "BUILTIN_CLASSES",
    "LOOKALIKE_CLASSES",
    "MAX_MODEL_EXTENT",
    "MESH_SUFFIXES",
    "MIN_MODEL_EXTENT",
    "UP_AXES",
    "ObjectModel",
    "ObjectSet",
    "ObjectSetConfig",
    "ProceduralSet",
    "builtin_object_set",
    "load_bop",
    "load_folder",
    "load_object_set",
    "lookalike_object_set",
    "lookalike_pairs",
    "models_info",
    "normalise_mesh",
    "object_set_from_config",
]

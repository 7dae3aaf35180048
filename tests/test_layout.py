"""The package layout's rules, read from the source: imports run one way (world -> perception -> planning ->
episode -> experiments -> commands), scripts import the package and never each other, and the pipeline's wiring
and the world set-up each have one owner."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).parent.parent
PACKAGE = ROOT / "jaxcls"

# What each layer must never import (prefixes of module names).
FORBIDDEN = {
    "jaxcls.world": ("jaxcls.perception", "jaxcls.planning", "jaxcls.episode", "jaxcls.active", "jaxcls.learn",
                     "jaxcls.experiments", "jaxcls.commands", "jaxcls.cli", "jaxcls.viz", "jaxcls.report"),
    "jaxcls.perception": ("jaxcls.world", "jaxcls.planning", "jaxcls.episode", "jaxcls.active", "jaxcls.learn",
                          "jaxcls.experiments", "jaxcls.commands", "jaxcls.cli", "jaxcls.viz", "jaxcls.report"),
    "jaxcls.planning": ("jaxcls.world", "jaxcls.episode", "jaxcls.active", "jaxcls.learn", "jaxcls.experiments",
                        "jaxcls.commands", "jaxcls.cli", "jaxcls.viz", "jaxcls.report"),
    "jaxcls.learn": ("jaxcls.commands", "jaxcls.cli", "jaxcls.episode", "jaxcls.active", "jaxcls.experiments"),
    "jaxcls.episode": ("jaxcls.commands", "jaxcls.cli", "jaxcls.learn", "jaxcls.experiments"),
    # The experiments' reusable logic (what experiments/ and benchmarks/ import) sits between the episode and
    # the commands.
    "jaxcls.experiments": ("jaxcls.commands", "jaxcls.cli"),
    # The shared helpers at the top sit below every layer.
    **{f"jaxcls.{m}": ("jaxcls.world", "jaxcls.perception", "jaxcls.learn", "jaxcls.experiments", "jaxcls.commands",
                       "jaxcls.cli")
       for m in ("allocator", "compile_cache", "devices", "geometry", "math", "config", "io", "report", "viz")},
}


def _module_name(path: Path, root: Path = ROOT) -> str:
    parts = path.relative_to(root).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports_of(path: Path) -> set[str]:
    """Every module ``path`` imports (absolute names; ``from a import b`` gives ``a`` and ``a.b``), at any
    depth (function-level imports count: a lazy import is still an import; ``if TYPE_CHECKING:`` ones do not)."""
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):  # imports for type checkers only are not imports at run time
        if isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING":
            node.body = []
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
            found.update(f"{node.module}.{alias.name}" for alias in node.names)
    return found


def _violations(rules: dict[str, tuple[str, ...]], root: Path = ROOT) -> list[str]:
    bad = []
    for path in sorted((root / "jaxcls").rglob("*.py")):
        name = _module_name(path, root)
        for layer, forbidden in rules.items():
            if name == layer or name.startswith(layer + "."):
                bad += [f"{name} imports {m}" for m in sorted(imports_of(path))
                        if any(m == f or m.startswith(f + ".") for f in forbidden)]
    return bad


def test_imports_run_one_way():
    assert _violations(FORBIDDEN) == []


def test_scripts_import_the_package_not_each_other():
    """experiments/ and benchmarks/ are command lines over the package (``jaxcls.experiments`` holds what they
    share): no script imports another, by name or from its file."""
    scripts = [*(ROOT / "experiments").glob("*.py"), *(ROOT / "benchmarks").glob("*.py")]
    names = {p.stem for p in scripts}
    bad = [f"{p.relative_to(ROOT)} imports {m}" for p in scripts for m in sorted(imports_of(p))
           if m.split(".")[0] in names]
    bad += [f"{p.relative_to(ROOT)} loads a module from a file" for p in scripts
            if "spec_from_file_location" in p.read_text()]
    assert bad == []


def test_the_rule_catches_a_backward_import(tmp_path):
    """The checker itself, on a copy of the package: a world module that imports perception is reported."""
    import shutil

    shutil.copytree(PACKAGE, tmp_path / "jaxcls", ignore=shutil.ignore_patterns("weights", "__pycache__"))
    (tmp_path / "jaxcls" / "world" / "_layout_probe.py").write_text(
        "def f():\n    from jaxcls.perception import tsdf\n    return tsdf\n")
    assert _violations(FORBIDDEN, tmp_path) == ["jaxcls.world._layout_probe imports jaxcls.perception",
                                                "jaxcls.world._layout_probe imports jaxcls.perception.tsdf"]


# The world set-up (object set -> scene -> models -> viewpoints -> MuJoCo model -> renderer) is owned by
# world.setup.make_world; the chain foreground -> integrate -> extract -> segment -> classify by
# perception.observation. Files that test or measure one stage on its own may call it directly.
_SETUP = re.compile(r"scenes\.build_model\(|\bbuild_model\(scene|scenes\.viewpoints\(|scene_centroid\(")
_SETUP_OWNERS = {"jaxcls/world/setup.py", "jaxcls/world/scenes.py", "tests/test_scenes.py", "tests/test_render.py",
                 "tests/test_dataset.py", "jaxcls/learn/clouds.py", "benchmarks/render.py"}
_WIRING = re.compile(r"foreground_depth\(")
_WIRING_OWNERS = {"jaxcls/perception/foreground.py", "jaxcls/perception/observation.py", "tests/test_segment.py",
                  "tests/test_inputs.py", "benchmarks/segment.py",
                  "tests/test_observe.py",  # checks observe against its stages composed by hand
                  "tests/test_tracking.py",  # the Open3D peer's source cloud: the frame's foreground
                  "benchmarks/ab_move.py"}  # its A side is the old revision's hand-wired chain, on purpose


# An episode (spec + classifier + model library + settings) is wired by episode.setup.make_episode.
_EPISODE = re.compile(r"Episode\.create\(")
_EPISODE_OWNERS = {"jaxcls/episode/setup.py", "jaxcls/episode/active.py"}


@pytest.mark.parametrize("pattern, owners", [(_SETUP, _SETUP_OWNERS), (_WIRING, _WIRING_OWNERS),
                                             (_EPISODE, _EPISODE_OWNERS)],
                         ids=["world set-up", "perception chain", "episode"])
def test_one_owner(pattern, owners):
    files = [*PACKAGE.rglob("*.py"), *(ROOT / "benchmarks").glob("*.py"), *(ROOT / "experiments").glob("*.py"),
             *(ROOT / "tests").glob("*.py"), *(ROOT / "notebooks").glob("*.ipynb")]
    users = {str(p.relative_to(ROOT)) for p in files if pattern.search(p.read_text()) and p.name != "test_layout.py"}
    assert users <= owners, f"wired by hand in {sorted(users - owners)}: use make_world / perception.observe"

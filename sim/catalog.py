"""The built-in scenes (`sim/scenes/*.toml`) and opening a scene by name or file path, or a
family's drawn line by `family:FAMILY:SEED` (`tofcut.sim.family`)."""

from __future__ import annotations

from pathlib import Path

from tofcut.sim.family import FAMILIES, family_scene, parse_family_name
from tofcut.sim.renderer import SceneSource
from tofcut.sim.scene_file import UnknownScene, load_scene

SCENES_DIR = Path(__file__).parent / "scenes"


def scene_names() -> list[str]:
    """Names of the scenes that ship with the package, sorted."""
    return sorted(p.stem for p in SCENES_DIR.glob("*.toml"))


def scene_path(name_or_path: str) -> Path:
    """The file of a built-in scene name, or the given path to a user's scene file."""
    builtin = SCENES_DIR / f"{name_or_path}.toml"
    if builtin.is_file():
        return builtin
    path = Path(name_or_path)
    if path.suffix == ".toml" and path.is_file():
        return path
    families = ", ".join(f"family:{f}:SEED" for f in FAMILIES)
    raise UnknownScene(
        f"no scene {name_or_path!r}: give a .toml file, {families}, or one of "
        f"{', '.join(scene_names())}"
    )


def open_scene(name_or_path: str, seed: int = 0) -> SceneSource:
    """A renderable source for a built-in scene, a scene file or a family's line
    (`family:conveyor:17`: the line drawn from seed 17); `seed` fixes noise and flash."""
    family = parse_family_name(name_or_path)
    if family is not None:
        return SceneSource(family_scene(*family), seed)
    return SceneSource(load_scene(scene_path(name_or_path)), seed)

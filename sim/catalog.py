"""The built-in scenes (`sim/scenes/*.toml`) and opening a scene by name or file path."""

from __future__ import annotations

from pathlib import Path

from tofcut.sim.renderer import SceneSource
from tofcut.sim.scene_file import SceneError, load_scene

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
    raise SceneError(
        f"no scene {name_or_path!r}: give a .toml file or one of {', '.join(scene_names())}"
    )


def open_scene(name_or_path: str, seed: int = 0) -> SceneSource:
    """A renderable source for a built-in scene or a scene file; `seed` fixes noise and flash."""
    return SceneSource(load_scene(scene_path(name_or_path)), seed)

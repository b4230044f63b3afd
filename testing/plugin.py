"""tofcut's pytest plugin: an emulated camera, an emulated conveyor controller on a
pseudo-terminal, and their faults, as fixtures (docs/testing.md).

pytest loads it in every project where tofcut is installed (the `pytest11` entry point), so
it only defines fixtures and two markers: nothing of tofcut is imported until a test asks
for one of its fixtures.

- `tofcut_camera`: a `CameraRig`, the emulated conveyor scene, fast (virtual clock), seed
  0, reconnecting; `@pytest.mark.tofcut_camera("tools", realtime=True, seed=3)` or
  indirect parametrization (a scene name, a capture to replay, or a dict of options) says
  otherwise.
- `tofcut_conveyor`: a `ConveyorRig`; it follows `tofcut_camera`'s belt when the test uses
  both and the scene has one, else 0.25 m/s on the host's clock
  (`@pytest.mark.tofcut_conveyor(speed_mps=0.4)` for options).
- `tofcut_camera_factory`, `tofcut_conveyor_factory`: make as many as a test needs, each
  closed after it (`tofcut.testing.emulated_camera` / `emulated_conveyor`'s arguments).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Any

import pytest

if TYPE_CHECKING:
    from tofcut.testing.camera import CameraRig
    from tofcut.testing.conveyor import ConveyorRig


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers",
        "tofcut_camera(scene='conveyor', *, realtime=False, seed=0, reconnect=True, "
        "loop=False): how tofcut's tofcut_camera fixture opens its emulated camera (scene: "
        "a scene, or a capture FILE.tofcap it replays)",
    )
    config.addinivalue_line(
        "markers",
        "tofcut_conveyor(speed_mps=None, *, registers=None, start_count=0, unit=1): "
        "how tofcut's tofcut_conveyor fixture starts its emulated controller",
    )


def _options(request: pytest.FixtureRequest, marker: str) -> tuple[tuple[Any, ...], dict[str, Any]]:
    """A fixture's arguments: indirect parametrization's (a scene name or a dict), else its
    marker's, else none."""
    param = getattr(request, "param", None)
    if isinstance(param, dict):
        return (), dict(param)
    if param is not None:
        return (param,), {}
    mark = request.node.get_closest_marker(marker)
    return (mark.args, dict(mark.kwargs)) if mark is not None else ((), {})


@pytest.fixture
def tofcut_camera_factory() -> Iterator[Callable[..., CameraRig]]:
    """Open emulated cameras (`tofcut.testing.emulated_camera`'s arguments); each is closed
    after the test."""
    from tofcut.testing.camera import emulated_camera

    with contextlib.ExitStack() as opened:

        def make(*args: Any, **kwargs: Any) -> CameraRig:
            return opened.enter_context(emulated_camera(*args, **kwargs))

        yield make


@pytest.fixture
def tofcut_camera(
    request: pytest.FixtureRequest, tofcut_camera_factory: Callable[..., CameraRig]
) -> CameraRig:
    """An emulated camera: the conveyor, fast, seed 0, reconnecting (see the module)."""
    args, kwargs = _options(request, "tofcut_camera")
    return tofcut_camera_factory(*args, **kwargs)


@pytest.fixture
def tofcut_conveyor_factory() -> Iterator[Callable[..., ConveyorRig]]:
    """Start emulated controllers (`tofcut.testing.emulated_conveyor`'s arguments); each is
    closed after the test."""
    from tofcut.testing.conveyor import emulated_conveyor

    with contextlib.ExitStack() as started:

        def make(*args: Any, **kwargs: Any) -> ConveyorRig:
            return started.enter_context(emulated_conveyor(*args, **kwargs))

        yield make


@pytest.fixture
def tofcut_conveyor(request: pytest.FixtureRequest) -> Iterator[ConveyorRig]:
    """An emulated controller on a pseudo-terminal, on `tofcut_camera`'s belt when the test
    uses both and its scene has one (see the module)."""
    from tofcut.testing.conveyor import emulated_conveyor

    args, kwargs = _options(request, "tofcut_conveyor")
    own = {"speed_mps", "clock", "camera"} & kwargs.keys()
    if not args and not own and "tofcut_camera" in request.fixturenames:
        camera: CameraRig = request.getfixturevalue("tofcut_camera")
        scene = camera.scene_model
        if scene is not None and scene.belt is not None:
            kwargs["camera"] = camera  # torn down after this fixture: pytest orders them
    with emulated_conveyor(*args, **kwargs) as rig:
        yield rig

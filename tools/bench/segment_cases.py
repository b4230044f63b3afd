"""The segmentation benchmark's cases on emulated 176×144 frames: one object per cut,
reference against fast (see `tofcut.tools.bench.cut_timing`); `tofcut bench` runs them."""

from __future__ import annotations

from tofcut.sim.truth import FrameTruth, ObjectTruth
from tofcut.tools.experiments.reproduce import deepest_pixel, extent_of
from tofcut.tracker.paper.segment import Energy, Target

CASES: tuple[tuple[str, str, Energy, int], ...] = (
    ("paper-fig1", "target-box", Energy.RANGE_DATA, 21),
    ("paper-fig1", "ball", Energy.RANGE_DATA, 21),
    ("paper-fig3", "box", Energy.RANGE_DATA, 21),
    ("paper-fig1", "target-box", Energy.RANGE_INTENSITY_SMOOTH, 11),
    ("paper-fig1", "ball", Energy.RANGE_SMOOTH, 11),
    ("tools", "wrench", Energy.RANGE_INTENSITY_SMOOTH, 11),
    ("tools", "hammer", Energy.RANGE_SMOOTH, 3),
    ("paper-fig1", "target-box", Energy.SUPPORT, 5),
    ("paper-fig1", "ball", Energy.SUPPORT, 5),
    ("paper-fig3", "box", Energy.SUPPORT, 5),
    ("tools", "wrench", Energy.SUPPORT, 5),
    ("tools", "hammer", Energy.SUPPORT, 5),
    ("tools", "tripod", Energy.SUPPORT, 5),
    ("robot", "robot", Energy.SUPPORT, 5),
)
"""(scene, object, energy, repetitions): the data-term cut around the object's true centroid
and extent (what the tracker does with its prediction), the §4.2 cuts from a seed deep
inside it, and the support energy from both (as `tofcut reproduce` gives it). The hammer's
§4.2 cut is the worst case: the weights join the hammer to the whole belt."""


def kind_of(energy: Energy) -> str:
    """ "data-term", "§4.2" or "support": the family of an energy and of its fast solver."""
    if energy is Energy.SUPPORT:
        return "support"
    return "§4.2" if energy.seeded else "data-term"


def case_target(truth: FrameTruth, obj: ObjectTruth, energy: Energy) -> Target:
    """A case's target: a seed deep inside the object for §4.2's energies, its true centroid
    and extent for the data terms, all three for the support energy."""
    pixel = deepest_pixel(truth.labels == obj.id)
    if energy.seeded:
        return Target(pixel=pixel)
    x, y, z = (float(c) for c in obj.centroid)
    return Target(
        pixel=pixel if energy is Energy.SUPPORT else None,
        point=(x, y, z),
        extent_m=extent_of(obj),
    )

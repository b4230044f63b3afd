"""What stands out, in pieces: the surfaces that measuring and finding tracks work on.

A mask (what stands out of the scenery and no track took, or all the tracks' masks) is cut
where neighbours are farther apart in 3D than `connect_m` (touching objects of different
heights come apart; one object's pixels stay together), or, given the range noise, than three
times the noise of their difference where that is more; in loud noise, on the median of each
pixel's neighbours within the mask, over a window that grows with the noise (3×3 to 7×7)
until a step stands out of it. Rigid objects on a known belt: a piece holding two
tops at different heights is two objects (`tofcut.tracker.tops`). The per-pixel loops are
compiled (`pieces_kernels`, `components_kernels`).
"""

from __future__ import annotations

from dataclasses import dataclass

from tofcut._types import F64, I32, U16, B
from tofcut.driver.belt import BeltGeometry
from tofcut.driver.frames import Frame
from tofcut.tracker import (
    background_kernels,
    components_kernels,
    frame_kernels,
    measure_kernels,
    pieces_kernels,
)
from tofcut.tracker.background import (
    MEDIAN_SHARES,
    BackgroundModel,
    on_belt_height,
    standing_regions,
)
from tofcut.tracker.params import TrackerParams
from tofcut.tracker.tops import facing_up, split_by_tops

STEP_APART = 4.0
"""A loud pixel's median window grows until a step of `connect_m` is this many times the
quietened noise: a step between two objects in 2–3 cm of noise (a dark box far away) stands
out of a 5×5 median, where a 3×3 one leaves the box's own top broken into specks."""


@dataclass(frozen=True, eq=False)
class Quietened:
    """A frame's points, ranges and range noise, quietened where loud (`quietened`)."""

    xyz: F64
    range: F64
    noise: F64


class Pieces:
    """Cuts masks into pieces (see the module's docstring)."""

    def __init__(self, params: TrackerParams) -> None:
        self.params = params

    def loose(
        self,
        frame: Frame,
        labels: U16,
        noise: F64,
        background: BackgroundModel,
        belt: BeltGeometry | None,
        seen: F64,
    ) -> I32:
        """Pieces of surface that stand out of the scenery and no track took (0 in `labels`),
        numbered from 1; `seen`: the frame's `BackgroundModel.seen_range`."""
        bg = background
        q = bg.params
        body = background_kernels.standing_out(
            bg.range, bg.sigma, bg.known, seen, frame.valid, labels, q.noise_factor,
            q.min_height_m,
        )  # fmt: skip
        body |= standing_regions(
            bg.range, bg.sigma, frame.valid & bg.known & (labels == 0), seen, q
        )
        if self.params.rigid and belt is not None:
            body[body] = on_belt_height(frame_kernels.points_in(frame.xyz, body, 0, 0), belt)
        # a step of `connect_m` parts touching objects of different heights, or three
        # times the noise where that is more: a surface in loud noise is not broken into
        # specks by steps within the noise
        return self.split(frame, body, noise, belt)

    def split(
        self,
        frame: Frame,
        body: B,
        noise: F64,
        belt: BeltGeometry | None,
        step_noise: bool = True,
    ) -> I32:
        """Connected pieces of `body`, cut where neighbours are farther apart in 3D than
        `connect_m`, or, given the range noise (`step_noise`), than three times the noise of
        their difference where that is more (a seed on a far, dark target); the pixel on the
        far side of such a step is left out."""
        quiet = quietened(frame, body, noise, self.params.connect_m)
        body = pieces_kernels.cut_at_steps(
            body, quiet.xyz, quiet.range, self.params.connect_m**2, quiet.noise, step_noise
        )
        pieces: I32 = components_kernels.label_pieces(body)
        return self.by_tops(quiet.xyz, body, pieces, quiet.noise, belt)

    def by_tops(self, xyz: F64, body: B, pieces: I32, noise: F64, belt: BeltGeometry | None) -> I32:
        """Rigid objects on a known belt: a piece holding two tops is two objects
        (`tofcut.tracker.tops`); others as they are. A piece of fewer than twice
        `min_pixels` holds no two tops of `min_pixels`: where none is larger, what faces up
        is not weighed."""
        p = self.params
        if not p.rigid or belt is None:
            return pieces
        if not (measure_kernels.piece_sizes(pieces)[1:] >= 2 * p.min_pixels).any():
            return pieces
        up = facing_up(body, xyz, noise, belt)
        if up is None:
            return pieces
        return split_by_tops(pieces, up, xyz, noise, belt, p.min_pixels)


def quietened(frame: Frame, body: B, noise: F64, step_m: float) -> Quietened:
    """The points, ranges and noise of `body` for finding its surfaces: where the range noise
    is a third of a `step_m` step or more, each pixel's range is the median of its
    neighbours in `body`, over the smallest window that leaves a step `STEP_APART` times its
    noise (a step between two objects stands out of that median's smaller noise; pixel by
    pixel it is lost in the noise). Elsewhere the frame's, unchanged."""
    xyz, rng, quiet = pieces_kernels.quieten(
        frame.xyz, frame.range, noise, body, step_m, MEDIAN_SHARES, STEP_APART
    )
    return Quietened(xyz, rng, quiet)

"""The depth-and-edge segmenter's settings (`DepthEdgeConfig`): read by the segmenter
(`perception.segment_depth`) and by the rules that join its pieces into faces
(`perception.piece_merge`), so kept below both.
"""
from __future__ import annotations

from dataclasses import dataclass

__all__ = ["DepthEdgeConfig"]


@dataclass(frozen=True)
class DepthEdgeConfig:
    """Every threshold of the depth-and-edge segmenter (the unit beside each field)."""

    jump_abs: float = 0.012          # m: depth step between neighbours that separates surfaces
    jump_rel: float = 0.012          # m per m^2 of depth: grows with the sensor's noise
    facing_cos: float = 0.80         # cos of the largest angle between face normal and shelf +y
    normal_step: int = 3             # px: finite-difference half step for normals
    canny_low: int = 40
    canny_high: int = 110
    line_extend: int = 14             # px: long straight edges are extended this far (seam gaps)
    line_min: int = 30               # px: shortest straight edge that is extended
    line_votes: int = 25
    chroma_gain: float = 2   # Lab a/b channels scaled by this before their own Canny
    min_face_m2: float = 0.0025      # smallest front face kept (5 x 5 cm)
    min_side_m: float = 0.04         # thinner pieces are tape/edges, not faces
    colour_merge: float = 11.0       # Lab distance under which two pieces are one box
    seam_veto: float = 0.5           # pieces whose border is more than this much colour edge stay apart
    seam_rect: float = 0.8           # ... when both are rectangles at least this full
    rgb_rect_fill: float = 0.86      # the same for photos without depth (`rgb_only`)
    rect_fill: float = 0.65          # a merged piece must fill its min-area rectangle this well
    tape_max_m: float = 0.09         # a tape band is at most this thick ...
    tape_rel: float = 1.25           # ... and at most this fraction of the pieces it joins
    tape_frac: float = 0.35          # ... at most this fraction of the face across the tape
    tape_centre: float = 0.3         # ... and its centre this close to the face's (of its size)
    tape_span: float = 0.85          # ... and runs across at least this fraction of the face
    tape_colour: float = 20.0        # Lab distance between the pieces on both sides of a tape
    wall_margin: float = 0.012       # m: points this close to the back wall are the shelf
    border_px: int = 3               # px: a piece this close to the image border may be cut by it ...
    border_min_px: int = 20          # ... when this many of its pixels are there; it is then kept ...
    border_side_m: float = 0.004     # ... down to this thickness (a strip of a face above the view)
    metric_px: bool = True           # line_min scales with f / depth (masks.pixel_scale)
    fill_hole_px: int = 4            # depth holes of at most this many pixels are filled for segmenting

"""The photo segmenter's settings (`PhotoConfig`): read by the segmenter (`perception.segment_photo`)
and by its superpixel merge tree (`perception.photo_tree`), so kept below both.
"""
from __future__ import annotations

from dataclasses import dataclass

__all__ = ["PhotoConfig"]


@dataclass(frozen=True)
class PhotoConfig:
    """Tuned on RCAN 418, 455, 547, 587, 633, 656 only (docs/perception-photos.md)."""

    work_side: int = 480          # px: the photo's long side while segmenting
    blur_sigma: float = 1.2
    grad_floor: float = 80.0      # Lab Sobel magnitude that is an edge in any photo
    seam_px: int = 9              # black-hat window: dark lines thinner than this are seams
    seam_floor: float = 20.0      # L units a seam is darker than its surround in any photo
    seam_weight: float = 1.0      # weight of the dark-seam map against the colour gradient
    levels: tuple[float, ...] = (0.15, 0.25, 0.35, 0.5)   # edge thresholds for components
    gaps: tuple[int, ...] = (0, 1, 2, 3)                 # px: seam gaps closed (erosion radius)
    tree: bool = True             # add the superpixel merge tree's regions to the candidates
    seed_px: int = 10             # px between superpixel seeds
    colour_weight: float = 0.5    # weight of the mean-colour difference in the merge order
    small_frac: float = 0.004     # regions below this share of the photo merge first
    min_frac: float = 0.006       # smallest carton: share of the photo
    max_frac: float = 0.45        # largest carton: share of the photo
    support_edge: float = 0.3     # edge strength that counts as outline support
    min_support: float = 0.5      # least share of the outline on an edge
    support_weight: float = 0.5   # weight of outline support against shape in the score
    q0: float = 0.55              # score a region must reach to be a carton
    split_min_part: float = 0.08  # a part that splits a candidate holds at least this share
    split_margin: float = 0.1     # and scores at least the candidate's score minus this
    split_cover: float = 0.45     # parts that cover this share of a candidate split it
    nest_max: float = 0.3         # a good region inside another, below this share of it, is a detail
    split_lines: bool = True      # cut a kept region along a dark seam line right across it
    line_edge: float = 0.25       # seam strength of such a line
    line_cover: float = 0.85      # share of the line's length on a seam
    line_min_part: float = 0.15   # each side of the cut holds at least this share of the region
    line_max_deg: float = 8.0     # lines within this many degrees of the region's axes
    max_overlap: float = 0.2      # a region this much covered by those taken is dropped

    def to_json(self) -> dict:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in vars(self).items()}

    @classmethod
    def from_json(cls, d: dict) -> "PhotoConfig":
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})

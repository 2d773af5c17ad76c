"""Parameters of the pipeline, grouped by stage, and the named presets.

Every constant of the method is a field here. The `paper` preset holds the values of
Dafni, Moses & Avidan (§3 and "Implementation details"); where the paper is silent
(patch size, candidate stride, geometry thresholds) the value is ours and is marked so.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass, field


@dataclass(frozen=True)
class GeometryParams:
    """Features, fundamental matrices and the support-set test (§3, "Implementation details")."""

    sift_features: int = 8000          # ours: SIFT keypoints per image at working resolution
    sift_contrast: float = 0.02        # ours: SIFT contrast threshold (OpenCV default 0.04 finds too few
                                       # keypoints on low-contrast surfaces: half the pairs lacked matches)
    ratio: float = 0.8                 # Lowe's ratio test, applied both ways, mutual matches only
    ransac_px: float = 1.5             # MAGSAC++ threshold in working-resolution pixels
    min_inliers: int = 40              # a pair needs at least this many F inliers
    min_spread: float = 0.12           # inlier convex hull / image area, in both images
    max_homography_share: float = 0.85  # if one homography explains this share of the F inliers, F is degenerate
    max_instability_px: float = 3.0    # median epipolar distance of inliers under an F re-fitted on half the data
    homography_pairs: bool = False     # paper: drop degenerate pairs; default: keep them as homography pairs
    homography_parallax_frac: float = 0.0125   # 95th pct. transfer error of static matches / max side (8 px at 640)
    triplet_check: bool = False        # paper: two-view tests only; default: pairs must agree across triplets
    triplet_max_px: float = 4.0        # median chained epipolar distance for a consistent triplet


@dataclass(frozen=True)
class PatchParams:
    """Epipolar patches and candidates (§3.1.1)."""

    patch_frac: float = 0.0375         # ours: patch length / working max side (24 px at 640)
    rows: int = 9                      # ours: samples across a strip (3 per HOG cell row)
    n_fans: int = 3                    # paper: fans shifted by 0, 1/3, 2/3 of the angular step
    along_overlap: int = 3             # paper: patches overlap by 2/3 along the strip -> 3 per pixel
    candidate_scales: tuple[float, ...] = (2 / 3, 1.0, 3 / 2)   # paper: three widths (values ours)
    candidate_step_frac: float = 1 / 6  # ours: candidate start positions every patch_length/6
    scale_from_features: bool = False  # centre candidate widths on the pair's SIFT scale ratio
    min_valid_ref: float = 1 / 3       # a reference patch needs this share of its samples in view
    min_valid_candidate: float = 2 / 3  # a candidate needs this share of its samples in view
    homography_reach_frac: float = 0.0  # homography pairs: 0 = H trusted everywhere; else inside the hull of
                                       # its inliers and this far (x working max side) beyond; farther, no evidence
    homography_search: int = 1         # homography pairs: search +-this many blocks (patch / 3) for parallax


@dataclass(frozen=True)
class DescriptorParams:
    """HOG + hue/saturation histogram (§3.1.2, "Implementation details")."""

    hog_cells: tuple[int, int] = (3, 3)  # ours: cells (across, along)
    hog_bins: int = 9                  # ours: unsigned orientation bins
    hog_floor: float = 0.05            # ours: flat prior (gradient magnitude per sample) so uniform patches match
    hist_bins: int = 10                # paper: 10 bins per channel, H and S
    w_hog: float = 2.0                 # paper: weight of HOG (cosine similarity)
    w_color: float = 1.0               # paper: weight of the colour histogram (intersection over union)
    norm_percentile: float = 0.0       # paper: 0 = min/max range of C over all pairs of the set
    color_normalise: bool = False      # paper: raw colours; default: map support colours to the reference's
    hist_achromatic: bool = False      # paper and default: every pixel by its hue. True puts grey and dark
                                       # pixels in one bin; measured: fewer static FPs, lower Jaccard (README)
    hist_smooth: bool = False          # paper: hard bins; default: each hue bin shares with its neighbours


@dataclass(frozen=True)
class AggregateParams:
    """Matching map and aggregation (§3.1.3 Eq. 2, §3.2 Eq. 3)."""

    sigma_frac: float = 1 / 3          # paper: sigma = max distance to the patch centre / 3
    remap: tuple[float, float] = (0.3, 0.7)  # paper: remap P(x|I_s) to (0.3, 0.7) before the product
    no_evidence: str = "no_match"      # paper: a patch with no candidate counts as unmatched
    threshold: float = 0.5             # ours: default threshold for the written masks
    refine_radius_frac: float = 0.0    # paper: none; default: guided filter radius / working max side
    refine_eps: float = 0.01           # guided filter regularisation (intensity variance units)


@dataclass(frozen=True)
class Params:
    preset: str = "paper"
    max_side: int = 640
    geometry: GeometryParams = field(default_factory=GeometryParams)
    patches: PatchParams = field(default_factory=PatchParams)
    descriptors: DescriptorParams = field(default_factory=DescriptorParams)
    aggregate: AggregateParams = field(default_factory=AggregateParams)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    def replace(self, **changes) -> "Params":
        return dataclasses.replace(self, **changes)

    def pair_key_material(self) -> str:
        """The parameters a per-pair matching result depends on, as canonical JSON."""
        d = {"max_side": self.max_side, "patches": dataclasses.asdict(self.patches),
             "descriptors": {k: v for k, v in dataclasses.asdict(self.descriptors).items()
                             if k in ("hog_cells", "hog_bins", "hist_bins", "hog_floor", "color_normalise",
                                      "hist_achromatic", "hist_smooth")}}
        return json.dumps(d, sort_keys=True)

    def geometry_key_material(self) -> str:
        return json.dumps({"max_side": self.max_side, "geometry": dataclasses.asdict(self.geometry)},
                          sort_keys=True)


def digest(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()[:24]


PRESETS: dict[str, Params] = {
    "paper": Params(preset="paper"),
    # Ours (issue 5): departures are listed in the README with their measured effect.
    "default": Params(
        preset="default",
        geometry=GeometryParams(homography_pairs=True, triplet_check=True),
        patches=PatchParams(homography_reach_frac=0.1),
        descriptors=DescriptorParams(color_normalise=True, hist_smooth=True),
        aggregate=AggregateParams(no_evidence="neutral", refine_radius_frac=0.02),
    ),
}


def get_preset(name: str) -> Params:
    try:
        return PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown preset {name!r}; choose one of {', '.join(PRESETS)}") from None

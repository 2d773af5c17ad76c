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
    # features.detect: 0 plain SIFT (every preset); k > 0 affine-simulated SIFT with k tilts (ASIFT).
    # Measured, not a preset's (README "Affine-simulated features"): 2 tilts give every rendered set
    # but two F's right at 100 %, but admit wide pairs whose evidence lowers 6 of 11 sets' Jaccard.
    affine_tilts: int = 0
    ransac_px: float = 1.5             # MAGSAC++ threshold in working-resolution pixels
    min_inliers: int = 40              # a pair needs at least this many F inliers
    min_spread: float = 0.12           # inlier convex hull / image area, in both images
    max_homography_share: float = 0.85  # if one homography explains this share of the F inliers, F is degenerate
    max_instability_px: float = 3.0    # median epipolar distance of inliers under an F re-fitted on half the data
    homography_pairs: bool = False     # paper: drop degenerate pairs; default: keep them as homography pairs
    homography_parallax_frac: float = 0.0125   # 95th pct. transfer error of static matches / max side (8 px at 640)
    triplet_check: bool = False        # paper: two-view tests only; default: pairs must agree across triplets
    triplet_max_px: float = 4.0        # median chained epipolar distance for a consistent triplet
    peer_homography: bool = False      # the peer baseline (peer.py): every pair aligned by one homography
    # Departure (default preset): in a set with a reconstruction, a two-view F (a photo the cameras did
    # not register) whose lines the two half-data refits put further apart than this (x working max
    # side; 16 px at 640) is not trusted. paper: 0 = no such test. Applied after the cached geometry.
    two_view_max_uncertainty_frac: float = 0.0
    # Large sets (screen.py; departure: the paper's sets are small and every pair is tried).
    screen_above: int = 16             # sets of more photos compare only the pairs a cheap screen picks
    screen_keep: int = 12              # each photo's partners with the most shared strong features
    screen_features: int = 256         # strongest keypoints per photo that the screen matches
    # Cameras for the whole set (reconstruction.py; departure, default preset). paper: two-view F's only.
    reconstruction: bool = False
    recon_min_matches: int = 15        # a pair's verified matches enter the reconstruction from this many
    recon_init_tri_angle: float = 2.0  # deg; COLMAP's 16 finds no initial pair in sets shot from few spots
    recon_init_inliers: int = 50       # COLMAP's 100 is more than many CrowdCam pairs have
    recon_max_seconds: int = 120       # the mapper gives up (and two-view geometry is used) after this
    # Sets of more photos than this get lighter bundle adjustments: redundant points are left out of
    # the mapper's global ones (COLMAP's ba_global_ignore_redundant_points3D, off by default), and the
    # final robust refinement stops at Ceres' default function tolerance (1e-6; COLMAP's is 0). A
    # hundred photos: one mapping run 66 -> 52 s, the refinement 21 -> 12.5 s, the same F precision
    # and Jaccard. Small sets keep COLMAP's settings (their mapping takes a second). Measured and not
    # kept: global adjustments less often (ratio 1.4 instead of 1.1): F precision down (96 -> 92-94 %).
    recon_light_ba_above: int = 24
    # Such a set's global adjustments in the mapper also stop when an iteration lowers the cost by
    # less than this share (COLMAP's 0: only the gradient stops them). A hundred photos: mapping
    # 50-56 -> 37-38 s a run, the cameras as close to the true ones (relative rotations 0.46 ->
    # 0.47 deg at the 90th percentile, focal lengths 0.40 % at it); 1e-4: 1.17 deg, not kept.
    recon_light_ba_tolerance: float = 1e-5
    recon_focal_guesses: tuple[float, ...] = (1.2, 0.8)  # initial focal / max side without EXIF: COLMAP's
                                       # default, then a second run; where they disagree, the photos do not decide
    recon_focal_agree: float = 0.15    # a camera whose focal length differs more between the runs is dropped
    recon_max_reproj_px: float = 1.5   # observations reprojecting farther after the robust refinement are dropped
    recon_focal_range: tuple[float, float] = (0.3, 4.0)  # plausible focal length / image side for a phone
    recon_min_registered: int = 4     # a model of three cameras cannot check itself: each camera answers to two
                                       # others only (courtyard_static: a 14 % focal error passed); two-view below
    recon_min_points: int = 20         # a registered photo must see this many reconstructed points
    recon_agree_px: float = 2.0        # median distance of a pair's own matches to the cameras' epipolar lines
    recon_min_covisible: int = 12      # a reconstruction pair needs this many points seen by both cameras,
    recon_min_overlap: float = 0.3     # or this share of each photo's sparse points in view of the other
    recon_min_baseline: float = 0.005  # baseline / scene depth below which F from cameras is meaningless
    recon_max_uncertainty_frac: float = 0.0125  # epipolar-line uncertainty limit / max side (8 px at 640)
    recon_rescue_planar: bool = True   # the cameras' F also for pairs the two-view tests found planar or poorly
                                       # spread. False: such pairs stay rejected (their matches cannot check F
                                       # off that plane or patch): F precision up (arc 89 -> 100 %), but
                                       # detection down where they were useful supports (README "Checks")
    recon_over_two_view: bool = False  # a pair of registered photos whose cameras' lines are too uncertain by the
                                       # estimate, but whose own two-view F passed with certain lines (within
                                       # two_view_max_uncertainty_frac; nothing without that gate): the
                                       # cameras' F all the same where it fits the pair's matches (median <=
                                       # recon_agree_px); not swept (uncertain lines). Ours (README "Checks"):
                                       # the estimate is cautious, and a two-view F is free off its matches'
                                       # planes (plaza: 2 of 7 such pairs 12-22 px off at the 90th percentile)


@dataclass(frozen=True)
class PatchParams:
    """Epipolar patches and candidates (§3.1.1)."""

    patch_frac: float = 0.0375         # ours: patch length / working max side (24 px at 640)
    rows: int = 9                      # ours: samples across a strip (3 per HOG cell row)
    n_fans: int = 3                    # paper: fans shifted by 0, 1/3, 2/3 of the angular step
    swept_fans: int = 0                # ours: fans of a pair that is also swept (its depth cue speaks for it; 0: n_fans)
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
    splat_step: int = 1                # paper: Eq. 2 at every pixel; 2: on a grid twice as coarse, resized (speed)
    remap: tuple[float, float] = (0.3, 0.7)  # paper: remap P(x|I_s) to (0.3, 0.7) before the product
    no_evidence: str = "no_match"      # paper: a patch with no candidate counts as unmatched
    threshold: float = 0.5             # ours: default threshold for the written masks
    refine_radius_frac: float = 0.0    # paper: none; default: guided filter radius / working max side
    refine_eps: float = 0.01           # guided filter regularisation (intensity variance units)
    # Calibration of the summed static log-odds z (with the sweep): P_dynamic = 1 / (1 + e^(scale (z - offset))).
    # crowdcam calibrate fits them on rendered sets that are not bundled: the scale on z, the offset where
    # the final maps (refined, with the plane-aligned difference) score best (calibrate.final_offset).
    calib_scale: float = 1.0
    calib_offset: float = 0.0
    mean_terms: bool = False           # paper: Eq. 3 sums the supports' log-odds; True: their mean per pixel
    # The plane-aligned colour difference as one more cue (peer.plane_log_odds; departure, default): each
    # support aligned by the homography of its matches, the median difference over the supports, added to
    # the map's log-odds with this weight (SetResult.with_plane_cue). 0 = off.
    plane_weight: float = 0.0
    plane_neutral: float = 34.5        # the median Lab difference that is no evidence (tau ln 10: P_peer 0.9)
    plane_dynamic_cap: float = 99.0    # the most the cue may count for "moving" (log-odds, before the weight): off
                                       # its plane the scene's parallax reads as change too
    swept_strips: float = 1.0          # weight of Eq. 3's strip term for a support that is also swept (the depth
                                       # cue speaks for it); 0: such a support speaks only through the depth cue


@dataclass(frozen=True)
class SweepParams:
    """Depth-consistent evidence (sweep.py; departure, default preset). paper: per-support strips."""

    enabled: bool = False
    scale: float = 0.5                 # sweep grid / working resolution (320 x 240 at 640); EVIDENCE_NOTES 10
    n_planes: int = 75                 # planes uniform in inverse depth over the reference's depth range (150
                                       # until the sweep was made faster: the same quality, README "Benchmark")
    ground_planes: int = 0             # planes parallel to the set's ground (when it has one), ground to camera
    window: int = 7                    # SSIM window on the sweep grid (14 px at 640)
    lab_weights: tuple[float, float, float] = (1.0, 2.0, 2.0)   # L, a, b: colour counts double
    direct_homography: bool = True     # homography pairs without cameras: SSIM of the aligned pixels as well,
    direct_max_parallax_frac: float = 0.005  # when their residual parallax is this small (3 px at 640)
    direct_reach_frac: float = 0.0     # and only inside the hull of the H inliers (and this x max side beyond)
    aligned_side: int = 0              # that direct comparison's grid: its longer side at most this (px; at least
                                       # the planes' grid; 0: the planes' grid); a photo whose swept supports are
                                       # all such fuses them there (SetResult.sweep_pairs)
    two_view: bool = False             # a photo without cameras: its epipolar supports swept over one pencil of
                                       # planes compatible with their F's (pencil.py)
    full_support: int = 1              # the cue counts in full where this many supports see the point
    lone_pencil_weight: float = 1.0    # the cue of a photo whose pencil of planes has one support (nothing
                                       # checks that support's F off its matches) counts this much
    min_seen_share: float = 0.0        # a plane counts where at least this share of the most supports seeing
                                       # the point at any plane see it (0: every plane, EVIDENCE_NOTES)
    lightness_mean: bool = True        # SSIM's luminance term on L (False: structure only on L)
    blur: float = 0.0                  # Gaussian sigma (grid px) before comparing
    best_share: float = 0.5            # fuse the best half of the supports that see a point (occlusion)
    min_agree: int = 1                 # but at least this many where that many see it (of two supports the best
                                       # half is one look-alike; 2: tabletop 0.53 -> 0.68, facade 0.20 -> 0.11)
    two_supports_agree: bool = False   # a reference with only two swept supports averages both (min_agree 2 for
                                       # it alone; default: tabletop 0.53 -> 0.57, plaza 0.29 -> 0.31)
    same_spot_frac: float = 0.0        # supports whose match moves less than this x the working side over the
                                       # reference's depth range (8 px at 640; shots from its spot) always count:
                                       # 0 = none are pinned. A fraction, as the other lengths: 16 px at 1280
    smooth_p2: float = 0.0             # > 0: the plane per pixel by semi-global regularisation of the fused
    smooth_p1: float = 0.3             # volume (jump penalty p2, next-plane penalty p1, in cost units), not the
    smooth_paths: int = 8              # best plane alone (EVIDENCE_NOTES point 9); 4 or 8 path directions
    smooth_unseen: float = 0.4         # the cost of a plane no support sees, for the regularisation
    ssim_c1: float = 1.0               # SSIM constants for Lab (L in 0..100): (0.01 * 100)^2, (0.03 * 100)^2
    ssim_c2: float = 9.0
    color_weight: float = 0.0          # share of the cost from the windows' mean colour distance (Lab)
    color_tau: float = 30.0            # that distance at which its cost saturates (a, b weighted)
    # Calibration of the fused cost into static log-odds, slope * (centre - cost): a cost of
    # `centre` is P_dynamic = 0.5 (crowdcam calibrate fits both on rendered sets not bundled).
    calib_slope: float = 12.0
    calib_centre: float = 0.28
    weight: float = 1.0                # the cue's weight beside Eq. 3's per-support terms (log-odds)


# The working size: photos are resized so that their longer side is at most this. Ours (the paper
# does not say). 1280, not 640, since stop 40: on the real `Slide` photos (1280 x 720) `default`
# went 0.335 -> 0.39 (Jaccard opt. per set) and the static control `facade_static` marked 0.32 ->
# 0.12 % of its pixels; README "Working size". Photos smaller than this are used as they are.
DEFAULT_MAX_SIDE = 1280


@dataclass(frozen=True)
class Params:
    preset: str = "paper"
    max_side: int = DEFAULT_MAX_SIDE
    geometry: GeometryParams = field(default_factory=GeometryParams)
    patches: PatchParams = field(default_factory=PatchParams)
    descriptors: DescriptorParams = field(default_factory=DescriptorParams)
    aggregate: AggregateParams = field(default_factory=AggregateParams)
    sweep: SweepParams = field(default_factory=SweepParams)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    def replace(self, **changes) -> "Params":
        return dataclasses.replace(self, **changes)

    def for_working_side(self, working_side: int) -> "Params":
        """These parameters for photos whose longer working side is `working_side` (PhotoSet.working_side):
        max_side no larger than it. Lengths that follow the working size (the patch length, the guided
        filter's radius) then follow the photos, not the limit they were loaded under, so a set of
        640-px photos gives the same results under any max_side from 640 up."""
        return self if self.max_side <= working_side else self.replace(max_side=int(working_side))

    def with_settings(self, settings: list[str]) -> "Params":
        """These parameters with settings "SECTION.FIELD=VALUE" changed (e.g. "sweep.min_agree=2",
        "geometry.recon_rescue_planar=false", "max_side=800"); the value is read as the field's
        current type (true/false, a number, comma-separated numbers for a tuple). Raises ValueError
        with one line naming the setting and the problem."""
        p = self
        for item in settings:
            name, eq, text = item.partition("=")
            name, text = name.strip(), text.strip()
            if not eq or not name or not text:
                raise ValueError(f"setting {item!r}: expected SECTION.FIELD=VALUE, e.g. sweep.min_agree=2")
            section, _, fname = name.rpartition(".")
            if section and section not in SECTIONS:
                raise ValueError(f"setting {item!r}: no section {section!r} (sections: {', '.join(SECTIONS)})")
            holder = getattr(p, section) if section else p
            names = [f.name for f in dataclasses.fields(holder)]
            if fname not in names or (not section and fname in SECTIONS + ("preset",)):
                where = f"in {section}" if section else "at the top level"
                raise ValueError(f"setting {item!r}: no field {fname!r} {where}")
            try:
                value = _parse_setting(text, getattr(holder, fname))
            except ValueError as e:
                raise ValueError(f"setting {item!r}: {e}") from None
            if name == "sweep.window" and (value < 1 or value % 2 == 0):     # a window centred on its pixel
                raise ValueError(f"setting {item!r}: the SSIM window must be an odd number of grid pixels, e.g. 7")
            if name == "aggregate.splat_step" and not 1 <= value <= 4:         # the patches' Gaussian spans ~8 px
                raise ValueError(f"setting {item!r}: the splat's grid step must be 1 (every pixel) to 4")
            holder = dataclasses.replace(holder, **{fname: value})
            p = dataclasses.replace(p, **{section: holder}) if section else holder
        return p

    @property
    def plane_cue(self) -> bool:
        """The map adds the plane-aligned difference (SetResult.with_plane_cue): a weight for it, and
        the depth-consistent fusion it is added to (Eq. 3's plain sum and the peer's map take none).
        Pairs compute the difference only then (run._task_pair)."""
        return self.aggregate.plane_weight > 0 and self.sweep.enabled and not self.geometry.peer_homography

    def pair_key_material(self) -> str:
        """The parameters a per-pair matching result depends on, as canonical JSON."""
        d = {"max_side": self.max_side, "patches": dataclasses.asdict(self.patches),
             "descriptors": {k: v for k, v in dataclasses.asdict(self.descriptors).items()
                             if k in ("hog_cells", "hog_bins", "hist_bins", "hog_floor", "color_normalise",
                                      "hist_achromatic", "hist_smooth")}}
        return json.dumps(d, sort_keys=True)

    def sweep_key_material(self) -> str:
        """The parameters a per-pair cost volume depends on (not the fusion's, nor the calibration)."""
        # two_view chooses which pairs are swept over a pencil (their keys hold its homographies), not
        # how a volume over the cameras' planes is made
        d = {k: v for k, v in dataclasses.asdict(self.sweep).items() if k not in SWEEP_FUSION + ("two_view",)}
        return json.dumps({"max_side": self.max_side, "sweep": d}, sort_keys=True)

    def geometry_key_material(self) -> str:
        """The parameters the cached features, pair geometry and reconstruction depend on (not the
        tests applied to them afterwards, run.detect_set)."""
        g = {k: v for k, v in dataclasses.asdict(self.geometry).items() if k not in POST_GEOMETRY}
        return json.dumps({"max_side": self.max_side, "geometry": g}, sort_keys=True)


# SweepParams fields of the per-reference fusion and calibration, not of a pair's cost volume
SWEEP_FUSION = ("enabled", "full_support", "lone_pencil_weight", "min_seen_share", "best_share", "min_agree",
                "two_supports_agree", "same_spot_frac", "smooth_p2", "smooth_p1", "smooth_paths", "smooth_unseen",
                "calib_slope", "calib_centre", "weight")

# GeometryParams fields applied to the cached geometry after it is loaded, not part of its key
POST_GEOMETRY = ("two_view_max_uncertainty_frac", "recon_over_two_view")


SECTIONS = tuple(f.name for f in dataclasses.fields(Params) if f.default_factory is not dataclasses.MISSING)


def _parse_setting(text: str, current):
    """A setting's text as the type of the field's current value."""
    if isinstance(current, bool):
        if text.lower() in ("true", "1", "on", "yes"):
            return True
        if text.lower() in ("false", "0", "off", "no"):
            return False
        raise ValueError(f"{text!r} is not true or false")
    if isinstance(current, tuple):
        parts = [t.strip() for t in text.split(",")]
        if len(parts) != len(current):
            raise ValueError(f"expected {len(current)} comma-separated values")
        return tuple(_parse_setting(t, c) for t, c in zip(parts, current))
    if isinstance(current, (int, float)):
        what = "a whole number" if isinstance(current, int) else "a number"
        try:
            value = type(current)(text)
        except ValueError:
            raise ValueError(f"{text!r} is not {what}") from None
        if value != value:
            raise ValueError("NaN is not a setting")
        return value
    return text


def digest(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()[:24]


PRESETS: dict[str, Params] = {
    "paper": Params(preset="paper"),
    # Ours (issue 5): departures are listed in the README with their measured effect.
    "default": Params(
        preset="default",
        geometry=GeometryParams(homography_pairs=True, triplet_check=True, reconstruction=True,
                                two_view_max_uncertainty_frac=0.025, recon_over_two_view=True),
        patches=PatchParams(homography_reach_frac=0.1, swept_fans=1),
        descriptors=DescriptorParams(color_normalise=True, hist_smooth=True),
        aggregate=AggregateParams(no_evidence="neutral", refine_radius_frac=0.02, mean_terms=True,
                                  calib_scale=1.641, calib_offset=-0.4,
                                  plane_weight=0.6, plane_dynamic_cap=0.5, splat_step=2),
        sweep=SweepParams(enabled=True, blur=1.0, calib_centre=0.30, ground_planes=24, same_spot_frac=0.0125,
                          smooth_p2=4.0, two_supports_agree=True, two_view=True,
                          lone_pencil_weight=0.5, aligned_side=640),
    ),
    # Not a method of ours: the 2-D baseline a user would try first (peer.py), for comparison.
    "peer-homography": Params(preset="peer-homography", geometry=GeometryParams(peer_homography=True)),
}


def get_preset(name: str) -> Params:
    try:
        return PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown preset {name!r}; choose one of {', '.join(PRESETS)}") from None

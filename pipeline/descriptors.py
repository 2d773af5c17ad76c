"""Patch descriptors (§3.1.2 and "Implementation details"): HOG compared by cosine similarity and a
2-D hue/saturation histogram (10 x 10 bins) compared by intersection over union.

Descriptors are computed in the strip frame (see patches.py): every sample of a strip carries its
gradient orientation relative to the strip's along direction (so HOG is measured relative to the
epipolar lines, in both images alike) and its colour bin. Window descriptors are differences of
cumulative sums along the strip, so any window, at any position and width, costs O(1).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .jit import LazyKernel

REMAP_BLOCK = 4096    # cv2.remap maps must stay below 32767 per side: sample in blocks of columns


@dataclass(frozen=True)
class ImageChannels:
    """Per-image inputs of the descriptors at working resolution.

    gx, gy: (h, w) float32 image gradients of the grey image;
    color_bin: (h, w) uint8 in [0, bins^2): hue bin * bins + saturation bin.
    """

    gx: np.ndarray
    gy: np.ndarray
    color_bin: np.ndarray

    @property
    def size(self) -> tuple[int, int]:
        return self.gx.shape


def image_channels(rgb: np.ndarray, hist_bins: int, achromatic: bool = False) -> ImageChannels:
    """(h, w, 3) uint8 RGB -> gradients and hue/saturation bins.

    achromatic: hue is undefined for grey and dark pixels, and there a small white-balance or
    exposure shift throws it into any bin. When True, pixels in the lowest saturation bin, or darker
    than one value bin, count in one "achromatic" bin (hue 0, saturation 0) instead."""
    gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.float32) / 255.0
    gray = cv2.GaussianBlur(gray, (0, 0), 0.8)
    gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=3)
    hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)      # H in [0, 180), S in [0, 256)
    hb = (hsv[..., 0].astype(np.int32) * hist_bins) // 180
    sb = (hsv[..., 1].astype(np.int32) * hist_bins) // 256
    color_bin = np.minimum(hb, hist_bins - 1) * hist_bins + np.minimum(sb, hist_bins - 1)
    if achromatic:
        grey = (sb == 0) | (hsv[..., 2].astype(np.int32) * hist_bins < 256)
        color_bin = np.where(grey, 0, color_bin)
    return ImageChannels(gx, gy, color_bin.astype(np.uint8))


def image_channels_for(rgb: np.ndarray, dp) -> ImageChannels:
    """image_channels with the binning of a DescriptorParams (the one call the pipeline makes)."""
    return image_channels(rgb, dp.hist_bins, dp.hist_achromatic)


def _remap(img: np.ndarray, xy: np.ndarray, interp: int) -> np.ndarray:
    """Sample img at points xy (..., 2) (pixel coordinates); returns (...) values."""
    shape = xy.shape[:-1]
    flat = xy.reshape(-1, 2).astype(np.float32)
    n = len(flat)
    pad = (-n) % REMAP_BLOCK
    m = np.concatenate([flat, np.full((pad, 2), -10.0, np.float32)]).reshape(-1, REMAP_BLOCK, 2)
    out = cv2.remap(img, m[..., 0], m[..., 1], interp, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return out.reshape(-1)[:n].reshape(shape)


@dataclass(frozen=True)
class StripFeatures:
    """Cumulative per-sample features of strips concatenated along one axis (N samples).

    hog_cum: (cells_across, N + 1, bins) float32, cumulative orientation histograms per cell row;
    color_cum: (N + 1, hist_bins^2) float32, cumulative colour-bin counts over all rows;
    valid_cum: (N + 1,) float32, cumulative count of in-image samples (over rows).
    """

    hog_cum: np.ndarray
    color_cum: np.ndarray
    valid_cum: np.ndarray
    rows: int


def strip_features(ch: ImageChannels, xy: np.ndarray, along: np.ndarray, across: np.ndarray,
                   cells_across: int, hog_bins: int, hist_bins: int) -> StripFeatures:
    """Features of strip samples.

    xy: (rows, N, 2) sample positions; along, across: (N, 2) unit vectors of the strip frame at
    each along index (orientation is measured from `along` towards `across`, unsigned).
    """
    rows, n = xy.shape[:2]
    h, w = ch.size
    valid = ((xy[..., 0] >= -0.5) & (xy[..., 0] <= w - 0.5) & (xy[..., 1] >= -0.5) & (xy[..., 1] <= h - 0.5))
    gx = _remap(ch.gx, xy, cv2.INTER_LINEAR)
    gy = _remap(ch.gy, xy, cv2.INTER_LINEAR)
    cb = _remap(ch.color_bin, xy, cv2.INTER_NEAREST)
    cell_of_row = ((np.arange(rows) * cells_across) // rows).astype(np.int64)
    hog_cum, color_cum, valid_cum = _strip_kernel(gx, gy, cb, valid, np.ascontiguousarray(along, np.float64),
                                                  np.ascontiguousarray(across, np.float64), cell_of_row,
                                                  cells_across, hog_bins, hist_bins * hist_bins)
    return StripFeatures(hog_cum=hog_cum, color_cum=color_cum, valid_cum=valid_cum, rows=rows)


def _strip_numba():
    """strip_features' binning and running sums in one compiled pass over the samples (numba):
    numpy spent most of a pair's time here, in full-size temporaries, bincounts and cumsums."""
    import math

    import numba

    pi = np.pi

    @numba.njit(cache=True, nogil=True)
    def kernel(gx, gy, cb, valid, along, across, cell_of_row, cells_across, hog_bins, nb):
        rows, n = gx.shape
        hog_cum = np.zeros((cells_across, n + 1, hog_bins), np.float32)
        color_cum = np.zeros((n + 1, nb), np.float32)
        valid_cum = np.zeros(n + 1, np.float32)
        cell = np.zeros((cells_across, hog_bins), np.float64)
        count = np.zeros(nb, np.float32)
        scale = hog_bins / pi
        v_total = 0.0
        for t in range(n):
            cell[:] = 0.0
            count[:] = 0.0
            n_valid = 0
            for r in range(rows):
                if not valid[r, t]:
                    continue
                n_valid += 1
                ga = gx[r, t] * along[t, 0] + gy[r, t] * along[t, 1]
                gc = gx[r, t] * across[t, 0] + gy[r, t] * across[t, 1]
                mag = math.sqrt(ga * ga + gc * gc)
                # unsigned orientation atan2(gc, ga) mod pi, within 2e-8 rad (tests/test_descriptors.py):
                # libm's atan2 took 25 ns a sample, 40 % of this pass. Folded to the upper half-plane,
                # the angle to the nearer axis is atan(mn / mx), and above tan(pi / 8) atan(u) =
                # pi / 4 + atan((u - 1) / (u + 1)): one division, then atan's series to u^15 on
                # |u| <= tan(pi / 8) (remainder below u^17 / 17 < 2e-8), selects without branches
                sg = -1.0 if (gc < 0.0 or (gc == 0.0 and ga < 0.0)) else 1.0
                ua, uc = ga * sg, gc * sg
                ax = abs(ua)
                mx, mn = max(ax, uc), min(ax, uc)
                big = mn > 0.41421356237309503 * mx
                num = mn - mx if big else mn
                den = mn + mx if big else mx
                u = num / den if den > 0.0 else 0.0
                q = u * u
                a = (0.7853981633974483 if big else 0.0) + u * (1.0 + q * (-1.0 / 3.0 + q * (
                    1.0 / 5.0 + q * (-1.0 / 7.0 + q * (1.0 / 9.0 + q * (-1.0 / 11.0 + q * (
                        1.0 / 13.0 - q / 15.0)))))))
                a = 0.5 * pi - a if uc > ax else a
                a = pi - a if ua < 0.0 else a
                a = a - pi if a >= pi else a
                # linear interpolation into the two nearest bins (centres at integers)
                ori = a * scale - 0.5
                b0f = math.floor(ori)
                frac = ori - b0f
                # ori lies in [-0.5, hog_bins - 0.5): the wrap is one compare, not an integer division
                b0 = int(b0f)
                b0 = b0 + hog_bins if b0 < 0 else b0
                b1 = 0 if b0 + 1 == hog_bins else b0 + 1
                c = cell_of_row[r]
                cell[c, b0] += mag * (1.0 - frac)
                cell[c, b1] += mag * frac
                count[cb[r, t]] += 1.0
            for c in range(cells_across):
                for b in range(hog_bins):
                    hog_cum[c, t + 1, b] = hog_cum[c, t, b] + np.float32(cell[c, b])
            for b in range(nb):
                color_cum[t + 1, b] = color_cum[t, b] + count[b]
            v_total += n_valid
            valid_cum[t + 1] = v_total
        return hog_cum, color_cum, valid_cum
    return kernel


_strip_kernel = LazyKernel(_strip_numba)


def strip_sums_numpy(gx, gy, cb, valid, along, across, cell_of_row, cells_across, hog_bins, nb):
    """The definition of _strip_numba's pass (tests compare them): per sample (rows, n) its gradient
    in the strip frame, its magnitude split between the two nearest of `hog_bins` unsigned
    orientation bins (np.arctan2), its colour bin counted; per along index t the running sums over
    t of the cells' HOG (cells_across, n + 1, hog_bins), the colour counts (n + 1, nb) and the valid
    samples (n + 1,), float32, as the kernel keeps them."""
    rows, n = gx.shape
    ga = gx * along[:, 0] + gy * along[:, 1]
    gc = gx * across[:, 0] + gy * across[:, 1]
    mag = np.sqrt(ga * ga + gc * gc)
    ori = np.mod(np.arctan2(gc, ga), np.pi) * (hog_bins / np.pi) - 0.5
    b0f = np.floor(ori)
    frac = ori - b0f
    b0 = b0f.astype(np.int64) % hog_bins
    r_idx, t_idx = np.nonzero(valid)
    c_idx = cell_of_row[r_idx]
    cell = np.zeros((cells_across, n, hog_bins), np.float64)
    np.add.at(cell, (c_idx, t_idx, b0[r_idx, t_idx]), (mag * (1.0 - frac))[r_idx, t_idx])
    np.add.at(cell, (c_idx, t_idx, (b0[r_idx, t_idx] + 1) % hog_bins), (mag * frac)[r_idx, t_idx])
    count = np.zeros((n, nb), np.float32)
    np.add.at(count, (t_idx, cb[r_idx, t_idx].astype(np.int64)), 1.0)
    hog_cum = np.zeros((cells_across, n + 1, hog_bins), np.float32)
    hog_cum[:, 1:] = np.cumsum(cell.astype(np.float32), axis=1)
    color_cum = np.zeros((n + 1, nb), np.float32)
    color_cum[1:] = np.cumsum(count, axis=0)
    valid_cum = np.zeros(n + 1, np.float32)
    valid_cum[1:] = np.cumsum(valid.sum(axis=0))
    return hog_cum, color_cum, valid_cum


@dataclass(frozen=True)
class WindowDescriptors:
    """Descriptors of windows [start, start + length) of the flat along axis.

    hog: (P, cells_across * cells_along * bins) float32, unit L2 norm (or zero);
    color: (P, hist_bins^2) float32, sums to 1 (or zero); valid: (P,) float32 share of in-image samples.
    """

    hog: np.ndarray
    color: np.ndarray
    valid: np.ndarray


def smooth_hist(color: np.ndarray) -> np.ndarray:
    """Spread each hue bin over its two hue neighbours with weights (1/4, 1/2, 1/4), circularly.

    color: (..., B * B) float32 with hue-major bins -> same shape, same sums. Hard hue bins split a
    colour that sits on a bin edge (red, pink and skin sit on the hue wrap at 0/180), and a small
    white-balance shift then empties the intersection; after smoothing, a one-bin shift keeps half
    of it. Saturation stays hard: smoothing it too cost more Jaccard than it saved false positives."""
    b = int(round(np.sqrt(color.shape[-1])))
    c = color.reshape(*color.shape[:-1], b, b)
    c = 0.5 * c + 0.25 * (np.roll(c, 1, axis=-2) + np.roll(c, -1, axis=-2))
    return c.reshape(color.shape).astype(np.float32)


def window_descriptors(sf: StripFeatures, start: np.ndarray, length: np.ndarray, cells_along: int,
                       hog_floor: float = 0.0, hist_smooth: bool = False) -> WindowDescriptors:
    """Descriptors of windows; hog_floor is a gradient magnitude per sample spread evenly over the
    orientation bins before normalisation (see DescriptorParams.hog_floor); hist_smooth applies
    `smooth_hist` to the colour histograms.

    One compiled pass per window (window_descriptors_numpy is the definition): numpy gathered the
    cumulative sums of every window into full-size temporaries (a hundred thousand candidates x 100
    colour bins, several times over), a fifth of a pair's time. Norms and sums are accumulated in
    float64, so the values differ from numpy's float32 reductions in their last bits (tested)."""
    start = np.ascontiguousarray(start, np.int64)
    length = np.ascontiguousarray(length, np.int64)
    hog, color, valid = _window_kernel(sf.hog_cum, sf.color_cum, sf.valid_cum, float(sf.rows), start, length,
                                       int(cells_along), float(hog_floor), bool(hist_smooth),
                                       int(round(np.sqrt(sf.color_cum.shape[1]))))
    return WindowDescriptors(hog, color, valid)


def window_valid(sf: StripFeatures, start: np.ndarray, length: np.ndarray) -> np.ndarray:
    """(P,) float32 share of in-image samples of windows [start, start + length): WindowDescriptors.valid
    alone, the same values."""
    start = np.asarray(start, np.int64)
    length = np.asarray(length, np.int64)
    return ((sf.valid_cum[start + length] - sf.valid_cum[start]) / (length * sf.rows)).astype(np.float32)


def _window_numba():
    import math

    import numba

    @numba.njit(cache=True, nogil=True)
    def kernel(hog_cum, color_cum, valid_cum, rows, start, length, ca, hog_floor, smooth, b):
        cr, _, bins = hog_cum.shape
        nb = color_cum.shape[1]
        P = len(start)
        hog = np.empty((P, cr * ca * bins), np.float32)
        color = np.empty((P, nb), np.float32)
        valid = np.empty(P, np.float32)
        bounds = np.empty(ca + 1, np.int64)
        raw = np.empty(nb, np.float32)
        floor_per_bin = np.float32(hog_floor / bins)
        for p in range(P):
            s0, n = start[p], length[p]
            for a in range(ca + 1):
                bounds[a] = s0 + (n * a) // ca
            ss = 0.0
            for r in range(cr):
                for a in range(ca):
                    extra = np.float32(0.0)
                    if hog_floor > 0:
                        extra = floor_per_bin * np.float32((bounds[a + 1] - bounds[a]) * (rows / cr))
                    o = (r * ca + a) * bins
                    for k in range(bins):
                        v = (hog_cum[r, bounds[a + 1], k] - hog_cum[r, bounds[a], k]) + extra
                        hog[p, o + k] = v
                        ss += float(v) * float(v)
            norm = np.float32(math.sqrt(ss)) + np.float32(1e-6)
            for k in range(cr * ca * bins):
                hog[p, k] = hog[p, k] / norm
            e = s0 + n
            total = 0.0
            for k in range(nb):
                v = color_cum[e, k] - color_cum[s0, k]
                raw[k] = v
                total += float(v)
            t = np.float32(max(total, 1e-6))
            for k in range(nb):
                raw[k] = raw[k] / t
            if smooth:                          # smooth_hist: hue neighbours 1/4, 1/2, 1/4, circularly
                for h in range(b):
                    lo, hi = ((h - 1) % b) * b, ((h + 1) % b) * b
                    for k in range(b):
                        color[p, h * b + k] = np.float32(0.5) * raw[h * b + k] + np.float32(0.25) * (
                            raw[lo + k] + raw[hi + k])
            else:
                for k in range(nb):
                    color[p, k] = raw[k]
            valid[p] = np.float32((valid_cum[e] - valid_cum[s0]) / (n * rows))
        return hog, color, valid
    return kernel


_window_kernel = LazyKernel(_window_numba)


def window_descriptors_numpy(sf: StripFeatures, start: np.ndarray, length: np.ndarray, cells_along: int,
                       hog_floor: float = 0.0, hist_smooth: bool = False) -> WindowDescriptors:
    """window_descriptors' definition in numpy (the compiled pass's values agree to float32's
    last bits)."""
    start = start.astype(np.int64)
    length = length.astype(np.int64)
    # Cell boundaries along the window; HOG cells are (cell row) x (cell along).
    bounds = start[:, None] + (length[:, None] * np.arange(cells_along + 1)[None]) // cells_along   # (P, ca+1)
    cum = sf.hog_cum[:, bounds]                                    # (cr, P, ca+1, bins)
    cells = cum[:, :, 1:] - cum[:, :, :-1]                         # (cr, P, ca, bins)
    if hog_floor > 0:
        n_in_cell = (bounds[:, 1:] - bounds[:, :-1]) * (sf.rows / cum.shape[0])      # (P, ca) samples
        cells = cells + (hog_floor / cells.shape[-1]) * n_in_cell[None, :, :, None].astype(np.float32)
    hog = np.transpose(cells, (1, 0, 2, 3)).reshape(len(start), -1)
    hog /= np.linalg.norm(hog, axis=1, keepdims=True) + 1e-6
    color = sf.color_cum[start + length] - sf.color_cum[start]
    color /= np.maximum(color.sum(axis=1, keepdims=True), 1e-6)
    if hist_smooth:
        color = smooth_hist(color)
    valid = (sf.valid_cum[start + length] - sf.valid_cum[start]) / (length * sf.rows)
    return WindowDescriptors(hog.astype(np.float32), color.astype(np.float32), valid.astype(np.float32))


def hog_similarity(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cosine similarity of unit-norm HOGs: (..., P, D) x (..., Q, D) -> (..., P, Q) in [0, 1]."""
    return np.matmul(a, np.swapaxes(b, -1, -2))


def color_similarity(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Intersection over union of normalised histograms: (P, B) x (Q, B) -> (P, Q) in [0, 1].

    For histograms that each sum to 1, sum(max) = 2 - sum(min), so IoU = I / (2 - I).
    """
    inter = np.minimum(a[:, None, :], b[None, :, :]).sum(axis=-1)
    return inter / np.maximum(2.0 - inter, 1e-6)

"""Write a run's outputs: maps (.npy), masks (.png), overlays (.jpg) and summary.json.

Everything is written into a staging folder beside the destination and renamed into place at the
end, so a failed or interrupted run leaves no half-written output (a previous output folder is
replaced only when the new one is complete).
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from .geometry import fundamental_to_original
from .reconstruction import cameras_in_original_frame
from .loading import Photo, decode_photo
from .run import SetResult


def to_original(prob: np.ndarray, photo: Photo) -> np.ndarray:
    """(h, w) working-resolution map -> (H, W) float32 at the photo's original size."""
    H, W = photo.orig_size
    if prob.shape == (H, W):
        return prob.astype(np.float32)
    return np.clip(cv2.resize(prob, (W, H), interpolation=cv2.INTER_LINEAR), 0.0, 1.0).astype(np.float32)


MASK_OUTLINE_RGB = (255, 40, 40)       # the mask's outline, as the inspector draws it


def heat_overlay(rgb: np.ndarray, prob: np.ndarray, mask: np.ndarray | None = None, alpha: float = 0.5) -> np.ndarray:
    """Blend a blue (static) to red (dynamic) heat map over the photo; (H, W, 3) uint8 RGB.

    The colour map is OpenCV's 'turbo', the inspector's (one colour language for the outputs,
    the inspector and the Rerun recording). mask: optional (H, W) bool; its outline is drawn in
    the inspector's red, on a dark border so that it reads on the red of the map.
    """
    heat = cv2.applyColorMap(np.clip(prob * 255 + 0.5, 0, 255).astype(np.uint8), cv2.COLORMAP_TURBO)[..., ::-1]
    out = (rgb.astype(np.float32) * (1 - alpha) + heat.astype(np.float32) * alpha).astype(np.uint8)
    if mask is not None and mask.any():
        contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        t = max(1, round(max(rgb.shape[:2]) / 400))
        cv2.drawContours(out, contours, -1, (0, 0, 0), t + 2, cv2.LINE_AA)
        cv2.drawContours(out, contours, -1, MASK_OUTLINE_RGB, t, cv2.LINE_AA)
    return out


def _imwrite(path: Path, img: np.ndarray, params: list[int] | None = None) -> None:
    ok, buf = cv2.imencode(path.suffix, img, params or [])
    if not ok:
        raise OSError(f"could not encode {path}")
    path.write_bytes(buf.tobytes())


def summary_dict(res: SetResult, threshold: float, extra: dict | None = None) -> dict:
    photos = res.photo_set.photos
    pairs = []
    for (i, j), g in sorted(res.pairs.items()):
        d = g.summary()
        d["ref"], d["sup"] = photos[i].stem, photos[j].stem
        d["F"] = None if g.F is None else fundamental_to_original(g.F, photos[i].scale, photos[j].scale).tolist()
        if d["uncertainty_px"] is not None:          # in the support's original pixels, like F
            d["uncertainty_px"] = round(g.uncertainty_px / photos[j].scale, 2)
        # how the pair speaks in the depth cue: over the cameras' planes, over the reference's pencil
        # of planes without cameras (pencil.py), compared directly after a homography, or not at all
        d["depth_cue"] = {"sweep": "cameras", "two-view": "pencil", "aligned": "aligned"}.get(res.sweep_kind(i, j))
        pairs.append(d)
    cams = res.cameras
    return {
        "set": res.photo_set.name,
        "input": str(Path(res.photo_set.root).resolve()),
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "F_convention": "x_support^T F x_reference = 0, original-resolution pixel coordinates, "
                        "(0, 0) = centre of the top-left pixel",
        "preset": res.params.preset,
        "parameters": res.params.to_dict(),
        "threshold": threshold,
        "camera_convention": "x = K R (X - C) in original-resolution pixel coordinates, (0, 0) = centre of the "
                             "top-left pixel; R world-to-camera rotation, C camera centre; world frame and scale "
                             "are the reconstruction's own (arbitrary)",
        "images": [{"stem": p.stem, "file": p.name, "size": list(p.orig_size), "working_size": list(p.size),
                    "supports": [photos[j].stem for j in res.supports[i]],
                    "has_map": res.dynamic[i] is not None,
                    "camera": (cameras_in_original_frame(cams, i, p.scale)
                               if cams is not None and cams.registered[i] else None),
                    "camera_note": (None if cams is None or cams.registered[i] else cams.reasons[i])}
                   for i, p in enumerate(photos)],
        "reconstruction": None if cams is None else {
            "registered": int(cams.n_registered), "points": int(len(cams.points)),
            "mean_reprojection_error_px": None if not np.isfinite(cams.mean_reproj_px) else round(cams.mean_reproj_px, 3),
            "seconds": round(cams.seconds, 2)},
        "pairs": pairs,
        "normaliser": res.normaliser.to_dict(),
        "timings": {k: round(v, 3) for k, v in res.timings.items()},
        "cache": {"hits": res.cache_hits, "misses": res.cache_misses},
        "warnings": list(res.photo_set.warnings) + list(res.warnings),
        **(extra or {}),
    }


def write_outputs(res: SetResult, out_dir: Path, threshold: float, extra: dict | None = None) -> Path:
    """Write maps/, masks/, overlays/ and summary.json for every photo with a map."""
    out_dir = Path(out_dir)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.partial-", dir=out_dir.parent))
    try:
        for sub in ("maps", "masks", "overlays"):
            (stage / sub).mkdir()
        for photo, dyn in zip(res.photo_set.photos, res.dynamic):
            if dyn is None:
                continue
            prob = to_original(dyn, photo)
            mask = prob > threshold
            np.save(stage / "maps" / f"{photo.stem}.npy", prob)
            _imwrite(stage / "masks" / f"{photo.stem}.png", mask.astype(np.uint8) * 255)
            rgb = _original_rgb(photo)
            _imwrite(stage / "overlays" / f"{photo.stem}.jpg", heat_overlay(rgb, prob, mask)[..., ::-1],
                     [cv2.IMWRITE_JPEG_QUALITY, 88])
        (stage / "summary.json").write_text(json.dumps(summary_dict(res, threshold, extra), indent=1))
        if out_dir.exists():
            trash = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.old-", dir=out_dir.parent))
            os.replace(out_dir, trash / "old")
            os.replace(stage, out_dir)
            shutil.rmtree(trash, ignore_errors=True)
        else:
            os.replace(stage, out_dir)
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise
    return out_dir


def _original_rgb(photo: Photo) -> np.ndarray:
    """The photo at original resolution (decoded again; the set keeps only the working copy)."""
    return decode_photo(photo.path)

"""Load a photo set: a folder of images, or a folder holding `images/` and optionally `gt/`.

Photos are decoded with EXIF orientation applied, converted to 8-bit RGB (grayscale, alpha and
16-bit inputs are accepted; HEIF/HEIC, the iPhone's format, through pillow-heif) and resized so
that their longer side is at most `max_side`.
Maps are computed at that working resolution and returned at each photo's original size.
"""

from __future__ import annotations

import functools
import hashlib
import io
import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from .params import DEFAULT_MAX_SIDE

HEIF_SUFFIXES = {".heic", ".heif"}   # iPhones' default: decoded through pillow-heif (libheif), not OpenCV
IMAGE_SUFFIXES = {".jpg", ".jpeg", ".png", ".tif", ".tiff", ".webp", ".bmp"} | HEIF_SUFFIXES
MAX_PIXELS = 120_000_000          # refuse larger photos (a 6000x4000 phone photo is 24 MP)
MAX_FILE_BYTES = 400 * 1024 * 1024
MAX_PHOTOS = 200                  # a set beyond this is refused with a message (pairs grow with n^2)
MAX_LISTED_SKIPS = 10             # skipped files named one by one; beyond, one line counts the rest


class InputError(Exception):
    """A problem with the user's input, reported as one line naming the file."""


@functools.cache
def _pil_image():
    """PIL's Image module, able to open HEIF/HEIC files too (pillow-heif's opener, registered on the
    first call; it applies the file's rotation and mirroring on decode and reads its EXIF)."""
    from PIL import Image
    try:
        import pillow_heif
        pillow_heif.register_heif_opener()
    except ImportError:                 # an install without it: HEIC files are then reported unreadable
        pass
    return Image


def _decode_heif(data: np.ndarray) -> np.ndarray | None:
    """A HEIF/HEIC file's bytes (uint8) as (H, W, 3) uint8 BGR (as OpenCV decodes), oriented; None
    when unreadable."""
    try:
        with _pil_image().open(io.BytesIO(data)) as im:
            return np.ascontiguousarray(np.asarray(im.convert("RGB"))[..., ::-1])
    except Exception:
        return None


@dataclass(frozen=True)
class Photo:
    """One photo of the set at working resolution.

    rgb: (h, w, 3) uint8, the photo resized so that max(h, w) <= max_side.
    orig_size: (H, W) of the decoded, EXIF-oriented original.
    scale: working / original size factor (<= 1).
    key: content hash of the file plus the working size, used by the cache.
    focal_prior_px: focal length in working pixels from the EXIF 35 mm-equivalent focal length,
    or None (a prior for the set reconstruction, reconstruction.py).
    """

    name: str
    stem: str
    path: Path
    rgb: np.ndarray
    orig_size: tuple[int, int]
    scale: float
    key: str
    focal_prior_px: float | None = None

    @property
    def size(self) -> tuple[int, int]:
        return self.rgb.shape[0], self.rgb.shape[1]


@dataclass(frozen=True)
class PhotoSet:
    name: str
    root: Path
    photos: tuple[Photo, ...]
    gt_dir: Path | None
    warnings: tuple[str, ...] = ()

    @property
    def working_side(self) -> int:
        """The longest side of any photo at working resolution (px): the max_side the set runs at
        (Params.for_working_side)."""
        return max(max(p.size) for p in self.photos)


def find_image_dir(root: Path) -> tuple[Path, Path | None]:
    """Return (folder with the photos, folder with ground truth or None)."""
    root = Path(root)
    if not root.exists():
        raise InputError(f"{root}: no such folder")
    if not root.is_dir():
        raise InputError(f"{root}: not a folder (give the folder that holds the photos)")
    images = root / "images"
    gt = root / "gt"
    if images.is_dir():
        return images, (gt if gt.is_dir() else None)
    return root, (gt if gt.is_dir() else None)      # photos at the root, ground truth beside them


def decode_photo(path: Path) -> np.ndarray:
    """Decode a file to (H, W, 3) uint8 RGB with EXIF orientation applied."""
    try:
        size = path.stat().st_size
    except OSError as e:
        raise InputError(f"{path}: cannot read ({e.strerror})") from None
    if size == 0:
        raise InputError(f"{path}: empty file")
    if size > MAX_FILE_BYTES:
        raise InputError(f"{path}: file too large ({size / 2**20:.0f} MB)")
    w_h = _declared_size(path)
    if w_h is not None and w_h[0] * w_h[1] > MAX_PIXELS:      # checked before decoding: no bomb goes off
        raise InputError(f"{path}: image too large ({w_h[0]}x{w_h[1]} pixels; at most {MAX_PIXELS // 10**6} MP)")
    try:
        data = np.fromfile(str(path), dtype=np.uint8)
    except OSError as e:
        raise InputError(f"{path}: cannot read ({e.strerror})") from None
    # IMREAD_ANYDEPTH keeps 16-bit; IMREAD_COLOR applies the EXIF orientation and drops alpha.
    img = _decode_heif(data) if path.suffix.lower() in HEIF_SUFFIXES else \
        cv2.imdecode(data, cv2.IMREAD_COLOR | cv2.IMREAD_ANYDEPTH)
    if img is None or img.size == 0:
        raise InputError(f"{path}: not a readable image (corrupt or unsupported format)")
    if img.shape[0] * img.shape[1] > MAX_PIXELS:
        raise InputError(f"{path}: image too large ({img.shape[1]}x{img.shape[0]} pixels)")
    if img.dtype == np.uint16:
        img = (img / 257.0 + 0.5).astype(np.uint8)
    elif img.dtype != np.uint8:
        img = np.clip(img.astype(np.float64) * (255.0 if img.max() <= 1.0 else 1.0), 0, 255).astype(np.uint8)
    if img.shape[0] < 32 or img.shape[1] < 32:
        raise InputError(f"{path}: image too small ({img.shape[1]}x{img.shape[0]} pixels)")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def _declared_size(path: Path) -> tuple[int, int] | None:
    """(width, height) the file's header declares, read without decoding the pixels (PIL), or None
    when PIL cannot tell (OpenCV may still read the file)."""
    try:
        import warnings

        Image = _pil_image()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")           # PIL's own DecompressionBombWarning: we decide here
            Image.MAX_IMAGE_PIXELS = None
            with Image.open(path) as im:
                return int(im.size[0]), int(im.size[1])
    except Exception:
        return None


def resize_to_max_side(rgb: np.ndarray, max_side: int) -> tuple[np.ndarray, float]:
    """(H, W, 3) uint8 -> (h, w, 3) uint8 with max(h, w) <= max_side, and the scale h/H."""
    h, w = rgb.shape[:2]
    s = min(1.0, max_side / max(h, w))
    if s >= 1.0:
        return rgb, 1.0
    size = (max(1, round(w * s)), max(1, round(h * s)))
    return cv2.resize(rgb, size, interpolation=cv2.INTER_AREA), size[1] / h


FULL_FRAME_DIAGONAL_MM = 43.27      # the 35 mm-equivalent focal length refers to this diagonal


def exif_focal_35mm(path: Path) -> tuple[float | None, str | None]:
    """(35 mm-equivalent focal length in mm, None) from the photo's EXIF, or (None, problem) when
    the tag is present but unusable (0, absurd), or (None, None) when there is none."""
    try:
        with _pil_image().open(path) as im:     # reads the header only, never the pixels
            value = im.getexif().get_ifd(0x8769).get(0xA405)
    except Exception:
        return None, None
    if value is None:
        return None, None
    try:
        f = float(value)
    except (TypeError, ValueError):
        return None, f"EXIF 35 mm focal length {value!r} is not a number"
    if not 8.0 <= f <= 600.0:
        return None, f"EXIF 35 mm focal length {f:g} mm is implausible"
    return f, None


def load_photo(path: Path, max_side: int, warn=None) -> Photo:
    path = Path(path)
    raw = decode_photo(path)
    rgb, scale = resize_to_max_side(raw, max_side)
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    # the working size the photo was loaded at, not the limit: a photo smaller than max_side keeps
    # one key under any limit above its size
    h.update(f"{max(rgb.shape[:2])}:{rgb.shape}".encode())
    f35, problem = exif_focal_35mm(path)
    if problem and warn is not None:
        warn(f"{path}: {problem}; ignored")
    focal = None if f35 is None else f35 / FULL_FRAME_DIAGONAL_MM * float(np.hypot(*rgb.shape[:2]))
    return Photo(name=path.name, stem=path.stem, path=path, rgb=np.ascontiguousarray(rgb),
                 orig_size=(raw.shape[0], raw.shape[1]), scale=scale, key=h.hexdigest()[:24], focal_prior_px=focal)


def list_images(folder: Path) -> tuple[list[Path], list[Path]]:
    """Image files (by suffix) and other, non-hidden files of a folder, sorted by name."""
    images, others = [], []
    for p in sorted(folder.iterdir()):
        if p.name.startswith(".") or p.is_dir():
            continue
        (images if p.suffix.lower() in IMAGE_SUFFIXES else others).append(p)
    return images, others


def load_set(root: Path, max_side: int = DEFAULT_MAX_SIDE, warn=None, gt_dir: Path | None = None) -> PhotoSet:
    """Load every photo of a set. Unreadable photos are skipped with a warning.

    Ground truth is `gt_dir` when given, else `gt/` beside the photos (or beside `images/`).
    Raises InputError when the folder is missing or empty, or fewer than two photos load, or
    gt_dir is given and is not a folder.
    """
    warnings: list[str] = []

    def _warn(msg: str) -> None:
        warnings.append(msg)
        if warn is not None:
            warn(msg)

    image_dir, found_gt = find_image_dir(Path(root))
    if gt_dir is not None:
        gt_dir = Path(gt_dir)
        if not gt_dir.is_dir():
            raise InputError(f"{gt_dir}: no such ground-truth folder")
    else:
        gt_dir = found_gt
    paths, others = list_images(image_dir)
    for p in others:
        _warn(f"{p}: skipped (not an image file type)")
    if not paths:
        raise InputError(f"{image_dir}: no images found (looked for {', '.join(sorted(IMAGE_SUFFIXES))})")
    if len(paths) > MAX_PHOTOS:
        raise InputError(f"{image_dir}: {len(paths)} image files; a set may hold at most {MAX_PHOTOS} photos "
                         "(split it, or pick the photos of one moment)")
    photos: list[Photo] = []
    stems: set[str] = set()
    contents: dict[str, str] = {}
    skipped = [0]

    def skip(msg: str) -> None:
        skipped[0] += 1
        if skipped[0] <= MAX_LISTED_SKIPS:
            _warn(msg)
    for p in paths:
        try:
            ph = load_photo(p, max_side, _warn)
        except InputError as e:
            skip(f"{e} -- skipped")
            continue
        if ph.stem in stems:
            skip(f"{p}: skipped (another photo has the same name stem {ph.stem!r})")
            continue
        if ph.key in contents:               # the same file twice says nothing about motion
            skip(f"{p}: skipped (the same photo as {contents[ph.key]})")
            continue
        stems.add(ph.stem)
        contents[ph.key] = p.name
        photos.append(ph)
    if skipped[0] > MAX_LISTED_SKIPS:
        _warn(f"{image_dir}: {skipped[0] - MAX_LISTED_SKIPS} more files skipped (not listed)")
    if len(photos) < 2:
        raise InputError(f"{image_dir}: fewer than two usable images ({len(photos)} of {len(paths)} loaded)")
    if gt_dir is not None:
        masks = sorted(p.stem for p in gt_dir.glob("*.png"))
        unmatched = [m for m in masks if m not in stems]
        if masks and len(unmatched) == len(masks):
            _warn(f"{gt_dir}: no ground-truth mask matches a photo (expected gt/<photo stem>.png, e.g. "
                  f"{photos[0].stem}.png); ground truth ignored")
            gt_dir = None
        elif unmatched:
            _warn(f"{gt_dir}: {len(unmatched)} mask(s) match no photo ({', '.join(unmatched[:3])}"
                  f"{'...' if len(unmatched) > 3 else ''})")
    name = Path(root).resolve().name
    return PhotoSet(name=name, root=Path(root), photos=tuple(photos), gt_dir=gt_dir, warnings=tuple(warnings))


def load_gt(gt_dir: Path, stem: str, size: tuple[int, int]) -> np.ndarray | None:
    """Ground truth `gt/<stem>.png`: (H, W) uint8 with 0 static, 255 moving, 128 don't care.

    Returns None when the file does not exist. Values other than 0/128/255 are snapped
    to the nearest of the three; a size mismatch is an InputError.
    """
    path = Path(gt_dir) / f"{stem}.png"
    if not path.exists():
        return None
    data = np.fromfile(str(path), dtype=np.uint8)
    gt = cv2.imdecode(data, cv2.IMREAD_GRAYSCALE) if data.size else None
    if gt is None:
        raise InputError(f"{path}: not a readable ground-truth mask")
    if gt.shape != tuple(size):
        raise InputError(f"{path}: ground truth is {gt.shape[1]}x{gt.shape[0]} but the photo is {size[1]}x{size[0]}")
    out = np.zeros_like(gt)
    out[gt >= 192] = 255
    out[(gt >= 64) & (gt < 192)] = 128
    return out


def load_gts(photo_set: PhotoSet) -> dict[str, np.ndarray]:
    """Ground truth of every photo of the set that has one: stem -> (H, W) uint8 (see load_gt)."""
    if photo_set.gt_dir is None:
        return {}
    gts = {p.stem: load_gt(photo_set.gt_dir, p.stem, p.orig_size) for p in photo_set.photos}
    return {k: g for k, g in gts.items() if g is not None}


def is_inside(child: Path, parent: Path) -> bool:
    try:
        Path(os.path.realpath(child)).relative_to(os.path.realpath(parent))
        return True
    except ValueError:
        return False

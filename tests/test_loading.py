"""Loading photo sets: formats, EXIF orientation, bit depths, sizes, bad files."""

import struct

import cv2
import numpy as np
import pytest

from pipeline.loading import InputError, load_gt, load_photo, load_set


def _exif_orientation_segment(value: int) -> bytes:
    """A minimal APP1/Exif segment holding only the Orientation tag (big-endian TIFF)."""
    ifd = struct.pack(">H", 1) + struct.pack(">HHIHH", 0x0112, 3, 1, value, 0) + struct.pack(">I", 0)
    payload = b"Exif\x00\x00" + b"MM\x00\x2a" + struct.pack(">I", 8) + ifd
    return b"\xff\xe1" + struct.pack(">H", len(payload) + 2) + payload


def _photo(h=60, w=80, seed=0):
    rng = np.random.default_rng(seed)
    return cv2.resize((rng.random((h // 4, w // 4, 3)) * 255).astype(np.uint8), (w, h))


def test_exif_orientation_is_applied(tmp_path):
    img = _photo(60, 80)
    ok, jpg = cv2.imencode(".jpg", img)
    data = jpg.tobytes()
    (tmp_path / "rot.jpg").write_bytes(data[:2] + _exif_orientation_segment(6) + data[2:])
    ph = load_photo(tmp_path / "rot.jpg", 640)
    assert ph.orig_size == (80, 60)            # rotated 90 degrees: portrait


@pytest.mark.parametrize("kind", ["gray", "rgba", "16bit", "tiff", "webp", "png"])
def test_formats_and_depths(tmp_path, kind):
    img = _photo()
    if kind == "gray":
        p, data = tmp_path / "a.png", cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    elif kind == "rgba":
        p, data = tmp_path / "a.png", np.dstack([img, np.full(img.shape[:2], 128, np.uint8)])
    elif kind == "16bit":
        p, data = tmp_path / "a.png", img.astype(np.uint16) * 257
    else:
        p, data = tmp_path / f"a.{ {'tiff': 'tif', 'webp': 'webp', 'png': 'png'}[kind] }", img
    assert cv2.imwrite(str(p), data)
    ph = load_photo(p, 640)
    assert ph.rgb.dtype == np.uint8 and ph.rgb.shape == (60, 80, 3)
    if kind == "16bit":
        assert np.abs(ph.rgb.astype(int) - img[..., ::-1]).max() <= 1


def test_iphone_heic_photos_load_upright_with_their_focal_length(tmp_path):
    """HEIC, the iPhone's default format (pillow-heif): decoded to RGB, its orientation applied,
    its EXIF 35 mm focal length read as for a JPEG."""
    import pillow_heif
    from PIL import Image
    pillow_heif.register_heif_opener()
    rgb = np.ascontiguousarray(_photo()[..., ::-1])                          # (60, 80) landscape
    exif = Image.Exif()
    exif[0x0112] = 6                                                         # shown turned 90 degrees
    exif.get_ifd(0x8769)[0xA405] = 26                                        # 26 mm equivalent
    Image.fromarray(rgb).save(tmp_path / "a.HEIC", exif=exif.tobytes(), quality=95)
    ph = load_photo(tmp_path / "a.HEIC", 640)
    assert ph.rgb.dtype == np.uint8 and ph.orig_size == (80, 60)             # portrait, as the phone showed it
    err = [np.abs(ph.rgb.astype(int) - np.rot90(rgb, k)).mean() for k in (-1, 1)]
    assert err[0] < 15 and err[0] < 0.5 * err[1]                             # turned clockwise (lossy HEVC)
    assert ph.focal_prior_px == pytest.approx(26 / 43.27 * 100.0, rel=1e-6)  # the diagonal of 60 x 80 is 100
    (tmp_path / "b.heic").write_bytes((tmp_path / "a.HEIC").read_bytes()[:200])
    with pytest.raises(InputError) as e:
        load_photo(tmp_path / "b.heic", 640)
    assert "b.heic" in str(e.value) and "not a readable image" in str(e.value)


def test_working_resolution_and_original_size(tmp_path):
    cv2.imwrite(str(tmp_path / "big.png"), _photo(300, 1000))
    ph = load_photo(tmp_path / "big.png", 250)
    assert ph.orig_size == (300, 1000) and max(ph.rgb.shape[:2]) == 250
    assert np.isclose(ph.scale, ph.rgb.shape[0] / 300, atol=0.01)


def test_set_layouts_and_skipped_files(tmp_path):
    flat = tmp_path / "flat"
    flat.mkdir()
    cv2.imwrite(str(flat / "a.jpg"), _photo(seed=1))
    cv2.imwrite(str(flat / "b.png"), _photo(70, 90, seed=2))        # a different size is normal
    (flat / "notes.txt").write_text("hello")
    (flat / "broken.jpg").write_bytes(b"\xff\xd8\xff\xe0 not really a jpeg")
    warnings = []
    ps = load_set(flat, 640, warn=warnings.append)
    assert [p.stem for p in ps.photos] == ["a", "b"] and ps.gt_dir is None
    assert any("notes.txt" in w and "not an image" in w for w in warnings)
    assert any("broken.jpg" in w and "not a readable image" in w for w in warnings)
    nested = tmp_path / "nested"
    (nested / "images").mkdir(parents=True)
    (nested / "gt").mkdir()
    for n in "xyz":
        cv2.imwrite(str(nested / "images" / f"{n}.jpg"), _photo(seed=ord(n)))
    ps = load_set(nested, 640)
    assert len(ps.photos) == 3 and ps.gt_dir == nested / "gt"


@pytest.mark.parametrize("case", ["missing", "file", "empty", "one", "corrupt_only"])
def test_bad_sets_raise_one_line_errors(tmp_path, case):
    d = tmp_path / "set"
    if case != "missing":
        d.mkdir()
    if case == "file":
        d.rmdir()
        d.write_text("x")
    if case == "one":
        cv2.imwrite(str(d / "a.jpg"), _photo())
    if case == "corrupt_only":
        (d / "a.jpg").write_bytes(b"garbage")
        (d / "b.png").write_bytes(b"")
    with pytest.raises(InputError) as e:
        load_set(d, 640)
    msg = str(e.value)
    assert "\n" not in msg and str(d) in msg


def test_ground_truth_values_and_size(tmp_path):
    gt = np.array([[0, 255, 130], [3, 250, 0]], np.uint8)
    cv2.imwrite(str(tmp_path / "a.png"), gt)
    out = load_gt(tmp_path, "a", (2, 3))
    assert out.tolist() == [[0, 255, 128], [0, 255, 0]]
    assert load_gt(tmp_path, "missing", (2, 3)) is None
    with pytest.raises(InputError, match="ground truth is 3x2"):
        load_gt(tmp_path, "a", (5, 5))


def test_a_photo_smaller_than_the_limit_is_the_same_photo_under_any_larger_limit(tmp_path):
    """A limit above a photo's size leaves it as it is, with the same cache key (the key names the
    working size, not the limit), and the set's working side is its largest photo's."""
    cv2.imwrite(str(tmp_path / "a.png"), _photo(60, 80, seed=1))
    cv2.imwrite(str(tmp_path / "b.png"), _photo(90, 120, seed=2))
    at_own, at_big = load_photo(tmp_path / "a.png", 80), load_photo(tmp_path / "a.png", 1280)
    assert at_own.key == at_big.key and np.array_equal(at_own.rgb, at_big.rgb) and at_big.scale == 1.0
    assert load_photo(tmp_path / "a.png", 40).key != at_own.key
    assert load_set(tmp_path, 1280).working_side == 120
    assert load_set(tmp_path, 100).working_side == 100

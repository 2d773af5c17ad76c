"""Inputs that try to hurt: each gets a clear one-line message or a sensible result, in bounded
time and memory, never a traceback. The files are made here, small on disk."""

import os
import shutil
import struct
import subprocess
import sys
import zlib

import cv2
import numpy as np
import pytest

from conftest import ROOT, SAMPLE_SETS

PHOTOS = sorted((SAMPLE_SETS / "tabletop_ball" / "images").glob("*.jpg"))


def png_declaring(width: int, height: int) -> bytes:
    """A tiny PNG file whose header declares width x height RGB pixels (the data is a stub)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 4096))
            + chunk(b"IEND", b""))


def run(*args, timeout=300):
    r = subprocess.run([sys.executable, "-m", "crowdcam", *map(str, args)], capture_output=True, cwd=ROOT,
                       timeout=timeout)
    return r.returncode, r.stdout.decode("utf-8", "replace"), r.stderr.decode("utf-8", "replace")


def detect(folder, tmp_path, *extra):
    return run("detect", folder, "--out", tmp_path / "out", "--max-side", "160", "--preset", "paper", "--quiet",
               "--workers", "1", "--cache-dir", tmp_path / "cache", *extra)


def with_photos(tmp_path, n=3):
    d = tmp_path / "set"
    d.mkdir()
    for p in PHOTOS[:n]:
        shutil.copy(p, d / p.name)
    return d


def assert_clean(err: str):
    assert "Traceback" not in err
    for line in err.splitlines():
        assert line.startswith("crowdcam: "), line            # every message is one whole line


@pytest.mark.parametrize("w,h", [(50000, 50000), (16000, 12500)])   # a decompression bomb; 200 megapixels
def test_huge_declared_images_are_refused_before_decoding(tmp_path, w, h):
    from pipeline.loading import InputError, decode_photo
    path = tmp_path / "big.png"
    path.write_bytes(png_declaring(w, h))
    with pytest.raises(InputError, match=f"too large \\({w}x{h}"):
        decode_photo(path)
    d = with_photos(tmp_path)
    shutil.copy(path, d / "big.png")
    code, _, err = detect(d, tmp_path)
    assert code == 0 and "big.png: image too large" in err
    assert_clean(err)


def test_a_symlink_loop_is_skipped(tmp_path):
    d = with_photos(tmp_path)
    os.symlink("loop.jpg", d / "loop.jpg")
    os.symlink(d, d / "sub")                      # a folder that contains itself
    code, _, err = detect(d, tmp_path)
    assert code == 0 and "loop.jpg" in err and "skipped" in err
    assert_clean(err)


def test_odd_file_names(tmp_path):
    """A name with a newline and one that is not UTF-8: the run works, messages stay one line,
    the outputs carry the names."""
    d = with_photos(tmp_path, 2)
    shutil.copy(PHOTOS[2], os.path.join(os.fsencode(d), b"odd\nname.jpg"))
    shutil.copy(PHOTOS[3], os.path.join(os.fsencode(d), b"caf\xe9.jpg"))
    (d / "notes\nfile.txt").write_text("x")           # a non-image with a newline: one warning line
    code, _, err = detect(d, tmp_path)
    assert code == 0, err
    assert_clean(err)
    assert "notes\\nfile.txt" in err
    import json
    summ = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert len(summ["images"]) == 4


def test_a_thousand_tiny_photos(tmp_path):
    """Refused at once by their number, before any is decoded; 150 of them are each skipped as too
    small, in a dozen lines."""
    d = tmp_path / "tiny"
    d.mkdir()
    ok, png = cv2.imencode(".png", np.full((16, 16, 3), 7, np.uint8))
    for k in range(1000):
        (d / f"t{k:04d}.png").write_bytes(png.tobytes())
    code, _, err = detect(d, tmp_path)
    assert code == 2 and "1000 image files" in err and err.count("\n") == 1
    for p in sorted(d.iterdir())[150:]:
        p.unlink()
    code, _, err = detect(d, tmp_path)
    assert code == 2 and "fewer than two usable images (0 of 150" in err
    assert "140 more files skipped" in err and err.count("\n") == 12
    assert_clean(err)


def test_too_many_photos_for_one_set(tmp_path):
    from pipeline.loading import MAX_PHOTOS
    d = tmp_path / "many"
    d.mkdir()
    ok, png = cv2.imencode(".png", np.full((40, 40, 3), 7, np.uint8))
    for k in range(MAX_PHOTOS + 1):
        (d / f"m{k:04d}.png").write_bytes(png.tobytes())
    code, _, err = detect(d, tmp_path)
    assert code == 2 and f"at most {MAX_PHOTOS} photos" in err and err.count("\n") == 1


def test_the_same_photo_twice(tmp_path):
    d = with_photos(tmp_path)
    shutil.copy(PHOTOS[0], d / "again.jpg")
    code, _, err = detect(d, tmp_path)
    assert code == 0 and "skipped (the same photo as" in err and "again.jpg" in err
    assert_clean(err)

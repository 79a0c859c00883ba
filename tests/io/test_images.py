"""Tests of ccs_kornia.io (images, files, boards): input expansion, robust image loading, board parsing, JSON, streaming."""

from __future__ import annotations

import json
import os

import cv2
import numpy as np
import pytest
import torch

from ccs_kornia.io.boards import parse_board
from ccs_kornia.io.files import write_json
from ccs_kornia.io.images import (
    ImageBatch,
    expand_inputs,
    image_pixels,
    iter_image_batches,
    load_image,
    load_image_gray,
    read_image,
    write_image,
)


def _ramp(h: int = 24, w: int = 32) -> np.ndarray:
    return (np.arange(h * w, dtype=np.float64).reshape(h, w) / (h * w - 1)).astype(np.float32)


@pytest.fixture()
def image_dir(tmp_path):
    ramp = _ramp()
    cv2.imwrite(str(tmp_path / "b.png"), (ramp * 255).round().astype(np.uint8))
    cv2.imwrite(str(tmp_path / "a.jpg"), cv2.cvtColor((ramp * 255).astype(np.uint8), cv2.COLOR_GRAY2BGR))
    cv2.imwrite(str(tmp_path / "c.PNG"), (ramp * 255).astype(np.uint8))
    (tmp_path / "notes.txt").write_text("not an image")
    (tmp_path / "sub").mkdir()
    cv2.imwrite(str(tmp_path / "sub" / "d.png"), (ramp * 255).astype(np.uint8))
    return tmp_path


class TestExpandInputs:
    def test_directory_sorted_non_recursive_images_only(self, image_dir):
        files, problems = expand_inputs([str(image_dir)])
        assert [os.path.basename(f) for f in files] == ["a.jpg", "b.png", "c.PNG"]
        assert problems == []

    def test_glob_file_and_duplicates(self, image_dir):
        files, problems = expand_inputs([str(image_dir / "*.png"), str(image_dir / "b.png"), str(image_dir / "notes.txt")])
        # plain files are kept whatever their extension (the loader says why they are skipped)
        assert [os.path.basename(f) for f in files] == ["b.png", "notes.txt"]
        assert problems == []

    def test_recursive_glob(self, image_dir):
        files, _ = expand_inputs([str(image_dir / "**" / "*.png")])
        assert sorted(os.path.basename(f) for f in files) == ["b.png", "d.png"]

    def test_problems(self, tmp_path):
        (tmp_path / "empty").mkdir()
        files, problems = expand_inputs([str(tmp_path / "empty"), str(tmp_path / "nope.png"), str(tmp_path / "*.jpg")])
        assert files == []
        reasons = dict(problems)
        assert "no image files" in reasons[str(tmp_path / "empty")]
        assert reasons[str(tmp_path / "nope.png")] == "no such file or directory"
        assert reasons[str(tmp_path / "*.jpg")] == "glob matched no file"


class TestLoadImage:
    def test_gray_8bit(self, tmp_path):
        ramp = _ramp()
        cv2.imwrite(str(tmp_path / "g.png"), (ramp * 255).round().astype(np.uint8))
        image, reason = load_image_gray(tmp_path / "g.png")
        assert reason == "" and image.dtype == np.float32 and image.shape == (24, 32)
        np.testing.assert_allclose(image, np.round(ramp * 255) / 255, atol=1e-6)

    def test_16bit_keeps_precision(self, tmp_path):
        ramp = _ramp()
        data = (ramp * 65535).round().astype(np.uint16)
        cv2.imwrite(str(tmp_path / "g16.png"), data)
        image, reason, depth = read_image(tmp_path / "g16.png")
        assert reason == "" and depth == 16
        np.testing.assert_allclose(image, data / 65535.0, atol=1e-6)
        # finer than 8-bit steps survive
        assert len(np.unique(image)) > 256

    def test_rgba_and_colour(self, tmp_path):
        ramp = (_ramp() * 255).round().astype(np.uint8)
        bgra = np.stack([ramp, ramp, ramp, np.zeros_like(ramp)], -1)  # fully transparent: alpha is ignored
        cv2.imwrite(str(tmp_path / "rgba.png"), bgra)
        image, reason = load_image_gray(tmp_path / "rgba.png")
        assert reason == ""
        np.testing.assert_allclose(image, ramp / 255.0, atol=1e-5)
        colour = np.zeros((16, 16, 3), np.uint8)
        colour[..., 2] = 255  # pure red in BGR
        cv2.imwrite(str(tmp_path / "red.png"), colour)
        grey, _ = load_image_gray(tmp_path / "red.png")
        np.testing.assert_allclose(grey, 0.299, atol=2e-3)  # OpenCV's BGR->grey weight of red
        rgb, _ = load_image(tmp_path / "red.png", gray=False)
        assert rgb.shape == (16, 16, 3) and rgb[0, 0, 0] == pytest.approx(1.0)

    def test_colour_is_converted_a_stripe_at_a_time_with_the_same_values(self, tmp_path, monkeypatch):
        """Large colour images are converted to float a stripe of rows at a time (bounded memory on big photos): the
        values are those of converting the whole image at once, 8- and 16-bit, grey and RGB output."""
        from ccs_kornia.io import images as io_module

        rng = np.random.default_rng(0)
        monkeypatch.setattr(io_module, "_STRIPED_PIXELS", 1000)
        for dtype, scale in ((np.uint8, 255.0), (np.uint16, 65535.0)):
            bgr = rng.integers(0, int(scale) + 1, size=(io_module._STRIPE_ROWS * 2 + 37, 50, 3)).astype(dtype)
            cv2.imwrite(str(tmp_path / "c.png"), bgr)
            whole = bgr.astype(np.float32) / scale
            grey, _ = load_image_gray(tmp_path / "c.png")
            rgb, _ = load_image(tmp_path / "c.png", gray=False)
            np.testing.assert_array_equal(grey, cv2.cvtColor(whole, cv2.COLOR_BGR2GRAY))
            np.testing.assert_array_equal(rgb, cv2.cvtColor(whole, cv2.COLOR_BGR2RGB))

    def test_colour_jpeg(self, tmp_path):
        colour = np.full((32, 32, 3), 128, np.uint8)
        cv2.imwrite(str(tmp_path / "c.jpg"), colour)
        image, reason = load_image_gray(tmp_path / "c.jpg")
        assert reason == "" and image.shape == (32, 32)
        assert abs(float(image.mean()) - 128 / 255) < 0.01

    @pytest.mark.parametrize(
        "name, content, expected",
        [
            ("text.png", b"hello, not an image", "not a readable image"),
            ("empty.jpg", b"", "empty file"),
        ],
    )
    def test_bad_files_give_reasons(self, tmp_path, name, content, expected):
        (tmp_path / name).write_bytes(content)
        image, reason = load_image_gray(tmp_path / name)
        assert image is None and expected in reason

    def test_truncated_png(self, tmp_path):
        cv2.imwrite(str(tmp_path / "full.png"), (np.random.default_rng(0).random((64, 64)) * 255).astype(np.uint8))
        data = (tmp_path / "full.png").read_bytes()
        (tmp_path / "cut.png").write_bytes(data[: len(data) // 2])
        image, reason = load_image_gray(tmp_path / "cut.png")
        assert image is None and "truncated" in reason

    def test_missing_and_directory(self, tmp_path):
        assert load_image_gray(tmp_path / "missing.png")[0] is None
        image, reason = load_image_gray(tmp_path)
        assert image is None and reason


class TestParseBoard:
    @pytest.mark.parametrize("text, expected", [("9x6", (9, 6)), ("4X6", (4, 6)), (" 8 x 6 ", (8, 6)), ("2x3", (2, 3))])
    def test_valid(self, text, expected):
        assert parse_board(text) == expected

    @pytest.mark.parametrize("text", ["9by6", "0x5", "1x1", "9x", "x6", "9x6x2", "-9x6", "9.5x6", "", "2x2", "1000x6"])
    def test_invalid(self, text):
        with pytest.raises(ValueError, match="invalid board size"):
            parse_board(text)

    def test_message_explains_inner_corners(self):
        with pytest.raises(ValueError, match="inner corners"):
            parse_board("1x6")


class TestWriteJson:
    def test_roundtrip_tensors_nan(self, tmp_path):
        path = tmp_path / "out.json"
        write_json(path, {"t": torch.tensor([1.0, float("nan")]), "a": np.arange(3), "f": np.float32(2.5), "inf": float("inf")})
        data = json.loads(path.read_text())
        assert data == {"t": [1.0, None], "a": [0, 1, 2], "f": 2.5, "inf": None}
        assert [p.name for p in tmp_path.iterdir()] == ["out.json"]  # no temporary file left

    def test_replaces_atomically_and_keeps_old_on_error(self, tmp_path):
        path = tmp_path / "out.json"
        write_json(path, {"v": 1})
        with pytest.raises(TypeError):
            write_json(path, {"v": object()})
        assert json.loads(path.read_text()) == {"v": 1}
        assert [p.name for p in tmp_path.iterdir()] == ["out.json"]

    def test_missing_directory(self, tmp_path):
        with pytest.raises(FileNotFoundError, match="does not exist"):
            write_json(tmp_path / "nope" / "out.json", {})


def test_write_image_roundtrip(tmp_path):
    ramp = _ramp()
    assert write_image(tmp_path / "r16.png", ramp, bit_depth=16)
    back, _, depth = read_image(tmp_path / "r16.png")
    assert depth == 16
    np.testing.assert_allclose(back, ramp, atol=1e-4)
    assert write_image(tmp_path / "r8.png", torch.from_numpy(ramp)[None])
    back8, _ = load_image_gray(tmp_path / "r8.png")
    np.testing.assert_allclose(back8, ramp, atol=0.5 / 255 + 1e-6)


class TestIterImageBatches:
    def test_batches_group_sizes_and_report_skips(self, tmp_path):
        files = []
        for k in range(5):
            size = (24, 32) if k != 2 else (20, 30)
            path = tmp_path / f"im{k}.png"
            cv2.imwrite(str(path), np.full(size, 10 * k, np.uint8))
            files.append(str(path))
        bad = tmp_path / "bad.png"
        bad.write_bytes(b"junk")
        files.insert(1, str(bad))
        batches = list(iter_image_batches(files, batch_size=2))
        assert all(isinstance(b, ImageBatch) for b in batches)
        seen = [p for b in batches for p in b.paths] + [p for b in batches for p, _ in b.skipped]
        assert sorted(seen) == sorted(files)  # every file exactly once
        for b in batches:
            if b.images is not None:
                assert b.images.shape[0] == len(b.paths) <= 2 and b.images.shape[1] == 1
                assert b.images.dtype == torch.float32
                assert 0.0 <= float(b.images.min()) and float(b.images.max()) <= 1.0
        sizes = {b.image_size for b in batches if b.images is not None}
        assert sizes == {(32, 24), (30, 20)}
        assert [p for b in batches for p, _ in b.skipped] == [str(bad)]

    def test_invalid_batch_size(self):
        with pytest.raises(ValueError):
            list(iter_image_batches([], batch_size=0))


def test_image_pixels_reads_png_and_jpeg_headers(tmp_path):
    """The pixel count from the header alone (baseline and progressive JPEG, 8/16-bit and colour PNG); other formats,
    missing files and garbage: None."""
    cases = {"a.png": np.zeros((37, 53), np.uint8), "b.png": np.zeros((20, 30, 3), np.uint16),
             "c.jpg": np.zeros((41, 67, 3), np.uint8), "d.bmp": np.zeros((5, 7), np.uint8)}
    for name, image in cases.items():
        cv2.imwrite(str(tmp_path / name), image)
    cv2.imwrite(str(tmp_path / "e.jpg"), np.zeros((33, 45), np.uint8), [cv2.IMWRITE_JPEG_PROGRESSIVE, 1])
    assert image_pixels(tmp_path / "a.png") == 37 * 53 and image_pixels(tmp_path / "b.png") == 600
    assert image_pixels(tmp_path / "c.jpg") == 41 * 67 and image_pixels(tmp_path / "e.jpg") == 33 * 45
    (tmp_path / "f.jpg").write_bytes(b"\xff\xd8\xff\xe0\x00")  # a truncated JPEG
    for name in ("d.bmp", "f.jpg", "missing.png"):
        assert image_pixels(tmp_path / name) is None

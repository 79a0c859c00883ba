"""The shape and argument checks every layer shares (ccs_kornia/runtime/checks.py)."""

from __future__ import annotations

import re

import pytest
import torch

from ccs_kornia.runtime.checks import (
    broadcast_shapes,
    check_board_size,
    check_correction,
    check_grey_images,
    check_points,
    check_same_shape,
    check_shape,
    check_tensor,
)


def _message(fn, *args, **kwargs) -> str:
    with pytest.raises(ValueError) as info:
        fn(*args, **kwargs)
    return str(info.value)


class TestCheckShape:
    def test_accepts_the_pattern(self) -> None:
        check_shape(torch.zeros(2, 5, 2), ["B", "N", "2"], "points must be (B, N, 2)")
        check_shape(torch.zeros(2, 5, 2), ["B", 5, 2], "points must be (B, 5, 2)")

    def test_names_the_shape_received(self) -> None:
        assert _message(check_shape, torch.zeros(2, 5), ["B", "N", "2"], "points must be (B, N, 2)") == (
            "points must be (B, N, 2), got (2, 5).")
        assert _message(check_shape, [1, 2], ["N", "2"], "points must be (N, 2)") == "points must be (N, 2), got list."


class TestCheckTensor:
    def test_patterns(self) -> None:
        check_tensor(torch.zeros(3, 3), "K", ["*", "3", "3"])
        check_tensor(torch.zeros(2, 4, 3, 3), "K", ["*", "3", "3"])
        check_tensor(torch.zeros(6, 10, 2), "corners", ["C", "V", "N", "2"], ["V", "N", "2"])
        check_tensor(torch.zeros(2, 6, 10, 2), "corners", ["C", "V", "N", "2"], ["V", "N", "2"])
        check_tensor(torch.zeros(2, 7), "valid", torch.Size([2, 7]))
        check_tensor(torch.zeros(4), "max_radius", [4])
        check_tensor(torch.zeros(()), "cost", [])

    def test_message_names_argument_shape_and_received(self) -> None:
        assert _message(check_tensor, torch.zeros(2, 3), "K", ["*", "3", "3"]) == "K must be (*, 3, 3), got (2, 3)."
        assert _message(check_tensor, torch.zeros(5, 2), "corners", ["C", "V", "N", "2"], ["V", "N", "2"]) == (
            "corners must be (C, V, N, 2) or (V, N, 2), got (5, 2).")
        assert _message(check_tensor, torch.zeros(2, 7), "valid", torch.Size([2, 6])) == "valid must be (2, 6), got (2, 7)."
        assert _message(check_tensor, torch.zeros(3), "max_radius", [4]) == "max_radius must be (4,), got (3,)."
        assert _message(check_tensor, None, "weights", ["B", "N"]) == "weights must be (B, N), got NoneType."

    def test_what_and_bound_sizes(self) -> None:
        assert _message(check_tensor, torch.zeros(2, 4), "distortion", ["B", "3"], what="coefficients (k0, k1, k2)") == (
            "distortion must be (B, 3) coefficients (k0, k1, k2), got (2, 4).")
        assert _message(check_tensor, torch.zeros(3, 5, 2), "corners", ["B", "N", "2"], B=2) == (
            "corners must be (B, N, 2) with B=2, got (3, 5, 2).")
        assert _message(check_tensor, torch.zeros(2, 5, 4), "image", ["C", "P", "P"], C=2, P=5) == (
            "image must be (C, P, P) with C=2, P=5, got (2, 5, 4).")
        check_tensor(torch.zeros(2, 5, 5), "image", ["C", "P", "P"], C=2, P=5)

    def test_a_letter_alone_is_any_size(self) -> None:
        # letters are not tied to each other unless bound: (C, P, P) alone accepts a non-square (C, 5, 4)
        check_tensor(torch.zeros(2, 5, 4), "image", ["C", "P", "P"])

    def test_same_alternatives_said_once(self) -> None:
        message = _message(check_tensor, torch.zeros(3, 24, 3), "object_points", [24, 3], [1, 24, 3], [1, 24, 3])
        assert message == "object_points must be (24, 3) or (1, 24, 3), got (3, 24, 3)."

    def test_one_line(self) -> None:
        message = _message(check_tensor, torch.zeros(2, 3, 4, 5, 6), "corners", ["C", "V", "N", "2"], ["V", "N", "2"],
                           what="for a 9x6 board", N=54)
        assert "\n" not in message
        assert re.fullmatch(r"corners must be \(C, V, N, 2\) or \(V, N, 2\) for a 9x6 board with N=54, "
                            r"got \(2, 3, 4, 5, 6\)\.", message)


class TestCheckSameShape:
    def test_same_shape(self) -> None:
        check_same_shape(torch.zeros(2, 5), "sigma", torch.ones(2, 5, dtype=torch.bool), "valid")

    def test_other_shapes(self) -> None:
        assert _message(check_same_shape, torch.zeros(2, 4), "sigma", torch.zeros(2, 5), "valid") == (
            "sigma must be (2, 5) (as valid), got (2, 4).")
        assert _message(check_same_shape, torch.zeros(5, 2), "target", torch.zeros(1, 5, 2), "pred") == (
            "target must be (1, 5, 2) (as pred), got (5, 2).")
        assert _message(check_same_shape, 3.0, "target", torch.zeros(1), "pred") == (
            "target must be (1,) (as pred), got float.")


class TestCheckPoints:
    def test_points(self) -> None:
        check_points(torch.zeros(2, 5, 2))
        check_points(torch.zeros(2, 5, 2), "corners", B=2, N=5)

    def test_exceptions(self) -> None:
        assert _message(check_points, torch.zeros(5, 2)) == "points must be (B, N, 2), got (5, 2)."
        assert _message(check_points, torch.zeros(2, 5, 2), "corners", B=3) == (
            "corners must be (B, N, 2) with B=3, got (2, 5, 2).")
        assert _message(check_points, torch.zeros(2, 5, 2), "corners", N=6) == (
            "corners must be (B, N, 2) with N=6, got (2, 5, 2).")


class TestCheckCorrection:
    def test_batch_one_or_batch(self) -> None:
        check_correction(torch.zeros(4, 5))
        check_correction(torch.zeros(1, 5), 3)
        check_correction(torch.zeros(3, 5), 3)

    def test_exceptions(self) -> None:
        assert _message(check_correction, torch.zeros(4, 3)) == (
            "correction must be (B, 5) coefficients (k0'..k4'), got (4, 3).")
        assert _message(check_correction, torch.zeros(2, 5), 3) == (
            "correction must be (1, 5) or (B, 5) coefficients (k0'..k4') with B=3, got (2, 5).")


class TestCheckGreyImages:
    def test_grey_images(self) -> None:
        check_grey_images(torch.zeros(2, 1, 8, 8))
        check_grey_images(torch.zeros(2, 1, 4, 4), min_side=0)

    def test_exceptions(self) -> None:
        assert _message(check_grey_images, torch.zeros(2, 3, 8, 8)) == (
            "images must be (B, 1, H, W) grey images, got (2, 3, 8, 8).")
        assert _message(check_grey_images, torch.zeros(1, 8, 8), "image") == (
            "image must be (B, 1, H, W) grey images, got (1, 8, 8).")
        assert _message(check_grey_images, torch.zeros(2, 1, 4, 8)) == "Images must be at least 8x8 px, got (4, 8)."


class TestBroadcastShapes:
    def test_as_torch(self) -> None:
        for shapes in [((3, 1, 4), (5, 4)), ((2, 1), (1, 3), ()), ((0, 1), (1, 6)), ((),)]:
            assert broadcast_shapes(*shapes) == torch.broadcast_shapes(*shapes)

    def test_exceptions(self) -> None:
        with pytest.raises(ValueError, match="cannot be broadcast"):
            broadcast_shapes((3, 4), (2, 4))


class TestCheckBoardSize:
    def test_board_size(self) -> None:
        assert check_board_size((9.0, 6)) == (9, 6)
        assert check_board_size((1, 1), min_side=1) == (1, 1)

    def test_exceptions(self) -> None:
        with pytest.raises(ValueError, match=r"board_size must be \(cols, rows\), got \(9, 6, 1\)"):
            check_board_size((9, 6, 1))
        with pytest.raises(ValueError, match="at least 2x2 inner corners"):
            check_board_size((1, 6))

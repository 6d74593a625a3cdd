"""No board in any image: the error points at the board description (size in squares,
polarity), not at recording more poses. Images with robot pose files, as another system
records them."""

from __future__ import annotations

import cv2
import pytest

from reconstruction.calibration.boards import BoardSpec
from scanner.commands.main import main
from tests.board_views import warped_board

POSE = "1 0 0 0.5\n0 1 0 0\n0 0 1 0.5\n0 0 0 1\n"  # matrix layout, metres


def _folder(tmp_path, spec: BoardSpec, invert: bool, poses: bool = True):
    image, _ = warped_board(spec)
    if invert:
        image = 255 - image
    folder = tmp_path / "images"
    folder.mkdir()
    for k in range(6):
        cv2.imwrite(str(folder / f"view{k}.png"), image)
        if poses:
            (folder / f"view{k}.txt").write_text(POSE)
    return folder


def _error(tmp_path, folder, capsys, *board) -> str:
    args = ["calibrate", "--offline", str(folder), *board, "--out", str(tmp_path / "out")]
    assert main(args) == 2
    message = capsys.readouterr().err.strip()
    assert "\n" not in message and "record" not in message  # one line, no "record more poses"
    assert not (tmp_path / "out" / "results").exists()
    return message


@pytest.mark.parametrize("poses", [True, False], ids=["hand-eye", "cameras-only"])
def test_a_board_size_larger_than_printed_asks_to_check_the_size(tmp_path, capsys, poses):
    folder = _folder(tmp_path, BoardSpec("chessboard", 10, 7, 0.02), False, poses)
    board = ["--board", "chessboard", "--board-size", "12x9", "--board-spacing", "0.02"]
    message = _error(tmp_path, folder, capsys, *board)
    assert "not found in any of the 6 images" in message
    assert "--board-size (counted in squares" in message and "--inverted" in message


def test_a_white_on_black_grid_without_inverted_asks_to_check_the_polarity(tmp_path, capsys):
    spec = BoardSpec("circles_asymmetric", 4, 11, 0.02, circle_diameter_m=0.008)
    folder = _folder(tmp_path, spec, True)
    board = ["--board", "circles_asymmetric", "--board-size", "4x11", "--board-spacing", "0.02"]
    message = _error(tmp_path, folder, capsys, *board)
    assert "black on white" in message and "--inverted (a white pattern on black)" in message
    # The same images with --inverted: the board is found (the error is then another one,
    # about the identical poses, not about the board).
    capsys.readouterr()
    main(
        ["calibrate", "--offline", str(folder), *board, "--inverted", "--out", str(tmp_path / "o2")]
    )
    assert "degenerate motions" in capsys.readouterr().err

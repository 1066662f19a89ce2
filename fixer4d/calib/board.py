"""The ChArUco calibration board: its spec, board.json, the printable image, corner detection.

A ChArUco board is a chessboard whose white squares hold ArUco markers: each detected marker
names the chessboard corners around it, so a partly visible or steeply tilted board still gives
corners with known board coordinates. Board coordinates are metres in the board's plane (z = 0),
origin at the outer corner of the first square, x along ``squares_x``.

Spec strings (``--board``): ``COLSxROWS[:SQUARE_M[:MARKER_M[:DICT]]]``, e.g.
``7x5:0.05:0.0375:DICT_4X4_50``; a missing marker size is ``MARKER_RATIO`` of the square. Or
the path of a board.json (``BoardSpec.write``).

A capture may keep its board videos in ``CAPTURE/board/`` (``BOARD_FOLDER``): one video or image
folder per camera, named like the capture's cameras, and the spec in ``board/board.json``.
"""
from __future__ import annotations

import re
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from fixer4d import atomic
from fixer4d.errors import InputError

BOARD_FOLDER = "board"
BOARD_JSON = "board.json"
BOARD_FORMAT = "fixer4d-charuco-board"
# OpenCV's customary marker/square ratio: the white rim left around each marker keeps the
# neighbourhood of every chessboard corner free of marker edges.
MARKER_RATIO = 0.75
# Printing resolution of ``write_board_image``: 300 dpi is what office printers resolve.
PRINT_DPI = 300
# White margin of the printed board, in squares: the outer black squares need light around them
# to be found.
PRINT_MARGIN_SQUARES = 0.5
# Fewer corners than this in one view constrain its board pose (6 unknowns) too weakly to help.
MIN_VIEW_CORNERS = 6
# Corner refinement window (half size) as a share of the local square size in pixels, at least
# 2 px: the window must stay inside the white rim that MARKER_RATIO leaves around the markers
# (1/8 of a square), or marker edges pull the corner. Measured on exact renders with 20-30 px
# squares: OpenCV's own refinement 0.15 px mean error, this one 0.09 px.
REFINE_WINDOW_SQUARES = 0.1
MIN_REFINE_WINDOW_PX = 2
_SPEC_RE = re.compile(r"^\s*(\d+)\s*x\s*(\d+)\s*(?::\s*([0-9.eE+-]+)\s*)?(?::\s*([0-9.eE+-]+)\s*)?(?::\s*(\w+)\s*)?$")
SPEC_SYNTAX = "COLSxROWS[:SQUARE_M[:MARKER_M[:DICT]]], e.g. 7x5:0.05:0.0375:DICT_4X4_50, or a board.json"


@dataclass(frozen=True)
class BoardSpec:
    """A ChArUco board: squares_x x squares_y squares of square_m metres, markers of marker_m
    metres from OpenCV's predefined ArUco ``dictionary``.

    Defaults: 7 x 5 squares give 24 inner corners per full view, enough for a well-constrained
    view while the squares stay large on the sheet; an odd row count sidesteps OpenCV's change of
    the pattern for even row counts (boards printed by OpenCV < 4.6 differ there). 0.05 m squares
    make a 0.35 x 0.25 m board that fits an A3 sheet with printer margins and is still decoded a
    few metres from a 1080p camera. DICT_4X4_50: the board has 17 markers; 4x4 bits are the
    largest cells per marker (decoded at the smallest image size) and the 50-id dictionary is the
    smallest holding 17, so its markers differ in the most bits.
    """

    squares_x: int = 7
    squares_y: int = 5
    square_m: float = 0.05
    marker_m: float = 0.0375
    dictionary: str = "DICT_4X4_50"

    def __post_init__(self) -> None:
        import cv2

        if self.squares_x < 2 or self.squares_y < 2:
            raise InputError(f"board {self.squares_x}x{self.squares_y}: needs at least 2x2 squares")
        if not 0 < self.marker_m < self.square_m:
            raise InputError(f"board: marker size {self.marker_m} m must be > 0 and smaller than the square "
                             f"({self.square_m} m)")
        if not hasattr(cv2.aruco, self.dictionary) or not self.dictionary.startswith("DICT_"):
            raise InputError(f"board: unknown ArUco dictionary {self.dictionary!r}; use one of OpenCV's "
                             f"(DICT_4X4_50, DICT_5X5_100, DICT_6X6_250, ...)")
        ids = re.search(r"_(\d+)$", self.dictionary)  # DICT_4X4_50 holds 50 markers
        if ids and int(ids.group(1)) < self.num_markers:
            raise InputError(f"board {self.squares_x}x{self.squares_y} needs {self.num_markers} markers but "
                             f"{self.dictionary} holds {ids.group(1)}; pick a larger dictionary")

    @property
    def num_markers(self) -> int:
        return self.squares_x * self.squares_y // 2

    @property
    def num_corners(self) -> int:
        return (self.squares_x - 1) * (self.squares_y - 1)

    def describe(self) -> str:
        return (f"ChArUco {self.squares_x}x{self.squares_y} squares of {self.square_m} m, markers {self.marker_m} m, "
                f"{self.dictionary}")

    def to_dict(self) -> dict:
        return {"format": BOARD_FORMAT, **asdict(self)}

    def write(self, path: str | Path) -> Path:
        """board.json, atomically."""
        return atomic.write_json(Path(path), self.to_dict())

    def cv_board(self):
        """The cv2.aruco.CharucoBoard."""
        import cv2

        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), self.square_m, self.marker_m, dictionary)

    def corners(self) -> np.ndarray:
        """(num_corners, 3) board coordinates (metres, z = 0) of the inner corners, by corner id."""
        return np.asarray(self.cv_board().getChessboardCorners(), np.float64).reshape(-1, 3)


def read_board_json(path: str | Path) -> BoardSpec:
    """A board.json; InputError naming the file and the bad entry."""
    from fixer4d.jsonfile import read_json_object

    path = Path(path)
    fix = f"write one with `fixer4d calibrate --board {SPEC_SYNTAX.split(',')[0]} --write-board board.png`"
    data = read_json_object(path, str(path), fix)
    try:
        return BoardSpec(int(data["squares_x"]), int(data["squares_y"]), float(data["square_m"]),
                         float(data["marker_m"]), str(data.get("dictionary", BoardSpec.dictionary)))
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{path}: malformed board ({exc!r}); it needs squares_x, squares_y, square_m, marker_m, "
                         f"dictionary; {fix}") from None


def parse_board(text: str | Path) -> BoardSpec:
    """A board.json path or a spec string (``SPEC_SYNTAX``) -> BoardSpec."""
    if Path(str(text)).suffix.lower() == ".json" or Path(str(text)).is_file():
        if not Path(str(text)).is_file():
            raise InputError(f"--board {text}: file not found")
        return read_board_json(text)
    m = _SPEC_RE.match(str(text))
    if not m:
        raise InputError(f"--board {text!r}: expected {SPEC_SYNTAX}")
    sx, sy, square, marker, dictionary = m.groups()
    try:
        square_m = float(square) if square else BoardSpec.square_m
        # rounded to whole nanometres: 0.0375, not 0.037500000000000006
        marker_m = float(marker) if marker else round(MARKER_RATIO * square_m, 9)
    except ValueError:
        raise InputError(f"--board {text!r}: sizes must be numbers in metres; expected {SPEC_SYNTAX}") from None
    return BoardSpec(int(sx), int(sy), square_m, marker_m, dictionary or BoardSpec.dictionary)


def find_board(capture: str | Path) -> tuple[Path, BoardSpec] | None:
    """(board capture folder, spec) when ``capture``/board/ holds board videos and a board.json, else None."""
    folder = Path(capture) / BOARD_FOLDER
    if (folder / BOARD_JSON).is_file():
        return folder, read_board_json(folder / BOARD_JSON)
    return None


def board_image(spec: BoardSpec, pixels_per_square: int, margin_px: int) -> np.ndarray:
    """(H, W) uint8 image of the board: square k spans pixels [margin + k * pps, margin + (k + 1) * pps).

    Board point (x, y) metres lies at OpenCV pixel (margin + x / square_m * pps - 0.5, same for y)."""
    size = (spec.squares_x * pixels_per_square + 2 * margin_px, spec.squares_y * pixels_per_square + 2 * margin_px)
    return spec.cv_board().generateImage(size, marginSize=margin_px, borderBits=1)


def write_board_image(spec: BoardSpec, path: str | Path, dpi: int = PRINT_DPI) -> Path:
    """The printable board (PNG, ``dpi`` dots per inch at 100 % scale, recorded in the file so a
    printer keeps the size) and its board.json beside it."""
    import io

    from PIL import Image

    pps = int(round(spec.square_m / 0.0254 * dpi))
    buffer = io.BytesIO()
    Image.fromarray(board_image(spec, pps, int(round(PRINT_MARGIN_SQUARES * pps)))).save(buffer, format="PNG",
                                                                                          dpi=(dpi, dpi))
    path = Path(path)
    atomic.write_bytes(path, buffer.getvalue())
    spec.write(path.with_suffix(".json"))
    return path


class CornerDetector:
    """ChArUco corners of one board in grayscale frames."""

    def __init__(self, spec: BoardSpec) -> None:
        import cv2

        self.spec = spec
        self.board = spec.cv_board()
        self._detector = cv2.aruco.CharucoDetector(self.board)

    def detect(self, gray: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """(ids (N,) int, uv (N, 2) float64 pixels in OpenCV's convention: pixel centres at integers)
        of the corners found, or None when fewer than ``MIN_VIEW_CORNERS`` are found or they lie
        on one line."""
        import cv2

        corners, ids, _, _ = self._detector.detectBoard(gray)
        if ids is None or len(ids) < MIN_VIEW_CORNERS or self.board.checkCharucoCornersCollinear(ids):
            return None
        xy = corners.reshape(-1, 2).astype(np.float32)
        gaps = np.linalg.norm(xy[:, None] - xy[None], axis=-1) + np.diag(np.full(len(xy), np.inf))
        square_px = float(np.median(gaps.min(1)))  # a corner's nearest neighbour is usually one square away
        half = max(MIN_REFINE_WINDOW_PX, int(round(REFINE_WINDOW_SQUARES * square_px)))
        criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 1e-4)
        xy = cv2.cornerSubPix(gray, xy.reshape(-1, 1, 2), (half, half), (-1, -1), criteria)
        return ids.ravel().astype(np.int64), xy.reshape(-1, 2).astype(np.float64)

"""Occupancy maps for the planner: load ROS, MovingAI, image and array maps into one grid.

World frame as in ROS (x right, y up, metres, origin at the lower-left corner); unknown cells
and everything outside the grid are obstacles; a distance field answers clearance queries.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import NamedTuple

import numpy as np
from scipy.ndimage import distance_transform_edt

from stepzoo.validate import check_memory

# The distance field is sampled on a lattice SUBDIV times finer than the cells. Obstacles are
# unions of whole cells, so at lattice points the field is exact, and reading it at the nearest
# lattice point costs at most sqrt(2)/SUBDIV cells of conservativeness (0.71 cell for 2).
# Real maps shipped with the package (MovingAI, ROS map_server), provenance in PROVENANCE.md.
MAP_DIR = Path(__file__).with_name("mapdata")
SUBDIV = 2
# Widest square of cells (a side) that OccupancyMap.disc_hits searches exactly: 9 x 9 covers a
# car's disc (radius about 1.2 m) on cells of 0.3 m and up, where the lattice bound is loosest.
EXACT_CELLS = 9
_FRAME = EXACT_CELLS // 2 + 1

# Distance fields of the last grids seen, keyed by the grid's content (never by a file name,
# so a changed map is never given an old field): a process that plans again and again on the
# same map (`stepzoo serve`) transforms it once.
FIELDS_KEPT = 2

# Peak memory a grid cell costs while a map is built: the occupancy, and the distance field
# on a lattice SUBDIV times finer with the transform's intermediates (measured with
# tracemalloc: docs/studies/measurements-behind-defaults-2026-11.md). A file's decoding adds
# its own per cell (DECODE_BYTES).
MAP_BYTES_PER_CELL = 144
# [bytes per cell] held while decoding: an image's pixels as float64 RGB and their grey mean;
# a MovingAI grid's one-character strings; an array's own items come from its header.
DECODE_BYTES = {"image": 32, "movingai": 16}
# A ROS map yaml is a dozen short lines: anything far larger is not one.
ROS_YAML_MAX_BYTES = 1 << 16

_MOVINGAI_FREE = frozenset(".GS")
_MOVINGAI_BLOCKED = frozenset("@OTW")
_ROS_MODES = ("trinary", "scale", "raw")


class Bounds(NamedTuple):
    """[m] the extent of a grid (unpacks as xmin, xmax, ymin, ymax)."""
    xmin: float
    xmax: float
    ymin: float
    ymax: float


@dataclass(frozen=True, eq=False)
class OccupancyMap:
    """A grid of obstacle cells; row 0 is the bottom row (y from origin_y to origin_y + res)."""

    occupied: np.ndarray  # bool (rows, cols), True = occupied or unknown
    resolution: float  # [m/cell]
    origin: tuple[float, float]  # world (x, y) [m] of the lower-left corner
    distance: np.ndarray = field(init=False, repr=False)  # [m] at lattice points, see SUBDIV
    _framed: np.ndarray = field(init=False, repr=False)  # occupied, framed by _FRAME cells

    def __post_init__(self):
        occupied = np.array(self.occupied, dtype=bool)
        if occupied.ndim != 2 or occupied.size == 0:
            raise ValueError(f"occupancy grid must be a non-empty 2-D array, got shape "
                             f"{occupied.shape}; pass a (rows, cols) array")
        resolution = _positive(self.resolution, "resolution")
        origin = tuple(float(v) for v in self.origin)
        if len(origin) != 2 or not all(np.isfinite(origin)):
            raise ValueError(f"map origin must be two finite numbers (x, y) [m], "
                             f"got {self.origin!r}")
        occupied.setflags(write=False)
        distance = _lattice_distance(occupied) * (resolution / SUBDIV)
        distance.setflags(write=False)
        object.__setattr__(self, "occupied", occupied)
        object.__setattr__(self, "resolution", resolution)
        object.__setattr__(self, "origin", origin)
        object.__setattr__(self, "distance", distance)
        object.__setattr__(self, "_framed", np.pad(occupied, _FRAME, constant_values=True))

    def bounds(self) -> Bounds:
        """[m] the grid's extent."""
        rows, cols = self.occupied.shape
        x0, y0 = self.origin
        return Bounds(x0, x0 + cols * self.resolution, y0, y0 + rows * self.resolution)

    def clearance(self, xy) -> np.ndarray:
        """(..., 2) [m] -> (...) [m]: a lower bound of the distance to the nearest obstacle.

        Positive only in free space; <= 0 inside obstacles, off the map and at non-finite points.
        """
        xy = np.asarray(xy, dtype=float)
        return self.clearance_at(xy[..., 0], xy[..., 1])

    def clearance_at(self, x, y) -> np.ndarray:
        """`clearance` of the points (x, y), given as two arrays (...) [m]."""
        step = self.resolution / SUBDIV
        col, row = (x - self.origin[0]) / step, (y - self.origin[1]) / step
        near_col, near_row = self.nearest_lattice(col, row)
        # The distance to a set is 1-Lipschitz: moving from the lattice point to (x, y) can
        # shrink it by at most the length of that move.
        gap_col, gap_row = col - near_col, row - near_row
        offset = np.sqrt(gap_col * gap_col + gap_row * gap_row) * step
        value = self.distance.take(near_row * self.distance.shape[1] + near_col) - offset
        # Only a non-finite point gives a non-finite offset, hence NaN or -inf here.
        return np.where(np.isnan(value), -np.inf, value)

    def nearest_lattice(self, col, row) -> tuple[np.ndarray, np.ndarray]:
        """Lattice coordinates [steps] -> int (column, row) of the nearest lattice point, clamped
        to the grid; NaN goes to 0.

        Points off the map land on the boundary lattice, where the field is zero, so their
        clearance goes negative without a separate test.
        """
        rows, cols = self.distance.shape
        return (np.fmin(np.fmax(np.rint(col), 0.0), cols - 1).astype(np.intp),
                np.fmin(np.fmax(np.rint(row), 0.0), rows - 1).astype(np.intp))

    def disc_hits(self, x, y, radius) -> np.ndarray:
        """Points as two arrays (...) [m] -> bool (...): an obstacle lies within `radius` [m]
        of the point, decided exactly from the cells around it (the lattice field's bound is
        loose by up to sqrt(2)/SUBDIV cells, which closes doors a car fits through on coarse
        maps). Where that needs more than EXACT_CELLS cells a side, the bound answers."""
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        k = math.ceil(radius / self.resolution)
        if 2 * k + 1 > EXACT_CELLS:
            return self.clearance_at(x, y) <= radius
        u, v = (x - self.origin[0]) / self.resolution, (y - self.origin[1]) / self.resolution
        rows, cols = self.occupied.shape
        # Off the grid (or on its edge) is in the obstacle region; non-finite is never free.
        hit = ~((u > 0) & (u < cols) & (v > 0) & (v < rows))
        u, v = np.where(hit, 0.5, u), np.where(hit, 0.5, v)
        col, row = np.floor(u).astype(np.intp), np.floor(v).astype(np.intp)
        reach2 = (radius / self.resolution) ** 2
        # The grid framed by obstacle cells (everything outside it is obstacle), flat.
        framed = self._framed.ravel()
        width = self._framed.shape[1]
        base = (row + _FRAME) * width + col + _FRAME
        gaps_v = []
        for dr in range(-k, k + 1):
            gap = np.maximum(np.maximum((row + dr) - v, v - (row + dr + 1)), 0.0)
            gaps_v.append(gap * gap)
        for dc in range(-k, k + 1):
            gap_u = np.maximum(np.maximum((col + dc) - u, u - (col + dc + 1)), 0.0)
            gap_u = gap_u * gap_u  # [cells^2] to the column
            for dr, gap_v in zip(range(-k, k + 1), gaps_v):
                hit |= (gap_u + gap_v <= reach2) & framed.take(base + (dr * width + dc))
        return hit

    def rectangle_hits(self, x, y, psi, length, width) -> np.ndarray:
        """Poses as three arrays (...) [m, m, rad] -> bool (...): an obstacle cell overlaps (or
        touches) the `length` x `width` [m] rectangle centred on (x, y) along psi, or the
        rectangle leaves the grid; decided exactly by separating axes against each cell of
        its bounding box. Non-finite poses hit."""
        x, y, psi = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (x, y, psi)))
        with np.errstate(invalid="ignore"):
            c, s = np.cos(psi), np.sin(psi)
        a, b = length / 2 / self.resolution, width / 2 / self.resolution  # [cells]
        u, v = (x - self.origin[0]) / self.resolution, (y - self.origin[1]) / self.resolution
        ex, ey = a * np.abs(c) + b * np.abs(s), a * np.abs(s) + b * np.abs(c)
        rows, cols = self.occupied.shape
        # The bounding box inside the open grid holds every corner there; NaN fails it.
        hit = ~((u - ex > 0) & (u + ex < cols) & (v - ey > 0) & (v + ey < rows))
        u, v, c, s = (np.where(hit, 0.5, w) for w in (u, v, c, s))
        ex, ey = np.where(hit, 0.0, ex), np.where(hit, 0.0, ey)
        col0, row0 = np.floor(u - ex).astype(np.intp), np.floor(v - ey).astype(np.intp)
        col1, row1 = np.floor(u + ex).astype(np.intp), np.floor(v + ey).astype(np.intp)
        # A cell's half extent along the rectangle's axes: 0.5 (|cos| + |sin|).
        half = 0.5 * (np.abs(c) + np.abs(s))
        flat = self.occupied.ravel()
        span_c = int((col1 - col0).max(initial=0)) + 1
        span_r = int((row1 - row0).max(initial=0)) + 1
        for dc in range(span_c):
            col = col0 + dc
            dx = col + 0.5 - u
            for dr in range(span_r):
                row = row0 + dr
                dy = row + 0.5 - v
                inside = (col <= col1) & (row <= row1)
                occupied = flat.take(np.where(inside, row * cols + col, 0)) & inside
                apart = ((np.abs(dx * c + dy * s) > a + half)
                         | (np.abs(dy * c - dx * s) > b + half))
                hit |= occupied & ~apart
        return hit

    def is_free(self, xy) -> np.ndarray:
        """(..., 2) [m] -> bool (...): clearance > 0."""
        return self.clearance(xy) > 0.0


def _positive(value, name: str) -> float:
    """`value` as a finite float > 0, else a ValueError naming `name`."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number > 0 [m/cell], got {value!r}") from None
    if not np.isfinite(number) or number <= 0.0:
        raise ValueError(f"{name} must be a finite number > 0 [m/cell], got {value!r}")
    return number


def _lattice_distance(occupied: np.ndarray) -> np.ndarray:
    """Exact distance [lattice steps] from every lattice point to the obstacle region (read
    only: it may be shared with other maps of the same grid).

    Lattice point (i, j) sits at (j, i) / SUBDIV cells from the lower-left corner. The obstacle
    region (closed occupied cells plus all outside the grid) has lattice-aligned corners, so its
    nearest point to a lattice point is itself a lattice point: a plain EDT is exact here.
    """
    return _grid_distance(occupied.shape, np.packbits(occupied).tobytes())


@lru_cache(maxsize=FIELDS_KEPT)
def _grid_distance(shape: tuple[int, int], packed: bytes) -> np.ndarray:
    """_lattice_distance of the grid of `shape` whose cells `packed` holds, a bit each."""
    bits = np.unpackbits(np.frombuffer(packed, np.uint8), count=shape[0] * shape[1])
    distance = fine_distance(bits.reshape(shape).astype(bool), SUBDIV)
    distance.setflags(write=False)
    return distance


def fine_distance(occupied: np.ndarray, sub: int) -> np.ndarray:
    """[lattice steps] the exact distance from each point of the lattice `sub` times finer
    than the cells (point (i, j) at (j, i) / sub cells from the lower-left corner) to the
    obstacle region (occupied cells and all outside the grid)."""
    fine = np.pad(np.repeat(np.repeat(occupied, sub, 0), sub, 1), 1, constant_values=True)
    # A lattice point is in the closed region if any of the four fine cells around it is.
    blocked = fine[:-1, :-1] | fine[1:, :-1] | fine[:-1, 1:] | fine[1:, 1:]
    return distance_transform_edt(~blocked)


def from_array(occupied, resolution, origin=(0.0, 0.0)) -> OccupancyMap:
    """Map from a 2-D array (nonzero = obstacle); occupied[0] is the bottom row."""
    return OccupancyMap(np.asarray(occupied) != 0, resolution, tuple(origin))


def load_map(path, cell_size=None, resolution=None) -> OccupancyMap:
    """Load a map, choosing the format by extension.

    .yaml/.yml: ROS map_server (resolution and origin from the file); .map: MovingAI;
    .png/.pgm: image, dark = occupied; .npy: array, nonzero = occupied, row 0 at the bottom.
    `cell_size` and `resolution` are both [m/cell]; give one for formats that lack it.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"map file not found: {path}; check the path")
    suffix = path.suffix.lower()
    if suffix in (".yaml", ".yml"):
        return _load_ros(path, _cell_size(path, cell_size, resolution, required=False))
    if suffix not in (".map", ".png", ".pgm", ".npy"):
        raise ValueError(f"unknown map format '{path.suffix}' for {path}; use .yaml/.yml (ROS), "
                         ".map (MovingAI), .png/.pgm (image) or .npy (array)")
    size = _cell_size(path, cell_size, resolution, required=True)
    if suffix == ".map":
        return from_array(_read_movingai(path)[::-1], size)
    if suffix == ".npy":
        return from_array(_read_npy(path), size)
    # A bare image has no thresholds: dark (occupancy above one half) is an obstacle.
    return from_array(_occupancy(_read_grey(path))[::-1] > 0.5, size)


def _cell_size(path: Path, cell_size, resolution, required: bool):
    """The one [m/cell] value given by either name, or None; ValueError if they conflict."""
    named = ((cell_size, "cell_size"), (resolution, "resolution"))
    given = [_positive(v, name) for v, name in named if v is not None]
    if len(given) == 2 and given[0] != given[1]:
        raise ValueError(f"cell_size {given[0]} and resolution {given[1]} disagree for {path}; "
                         "give one of them")
    if required and not given:
        raise ValueError(f"{path.name} does not store its cell size; give one in metres per cell "
                         "(cell_size=... or resolution=...)")
    return given[0] if given else None


def check_cells(path: Path, rows: int, cols: int, decode_bytes: float):
    """UsageError (naming the size and --max-memory) if building a map of rows x cols cells
    from `path` would take more memory than allowed (validate.check_memory), before any cell
    is decoded."""
    cells = float(rows) * float(cols)
    check_memory(f"map {path} of {rows} x {cols} cells", cells * (MAP_BYTES_PER_CELL
                                                                  + decode_bytes),
                 f"{cells:.3g} cells x {MAP_BYTES_PER_CELL + decode_bytes:g} bytes",
                 "give a smaller map or larger cells (downsample it)")


def image_shape(path: Path) -> tuple[int, int] | None:
    """(rows, cols) from a PNG's IHDR or a PGM/PBM/PPM header, read without decoding; None for
    other formats (Pillow then reads the size from the header it knows)."""
    with open(path, "rb") as fh:
        head = fh.read(512)
    if head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR" and len(head) >= 24:
        cols, rows = struct.unpack(">II", head[16:24])
        return rows, cols
    if head[:1] == b"P" and head[1:2] in b"123456" and len(head) > 2:
        words = []
        for line in head[2:].split(b"\n"):
            words += line.split(b"#")[0].split()
            if len(words) >= 2:
                break
        if len(words) >= 2 and words[0].isdigit() and words[1].isdigit():
            return int(words[1]), int(words[0])
    return None


def _read_grey(path: Path) -> np.ndarray:
    """Image as float grey values 0..255, colour channels averaged (alpha ignored), as ROS does."""
    # Pillow and PyYAML are imported by the readers of their formats: a scenario of
    # rectangles, or a MovingAI map, needs neither.
    from PIL import Image, UnidentifiedImageError
    shape = image_shape(path)
    if shape is not None:           # before Pillow, whose own bomb limit is no memory limit
        check_cells(path, *shape, DECODE_BYTES["image"])
    try:
        with Image.open(path) as image:
            # Opening reads the header alone: the size is known before the pixels are.
            check_cells(path, image.size[1], image.size[0], DECODE_BYTES["image"])
            image.load()
            bands = image.getbands()
            if bands in (("L",), ("1",), ("L", "A"), ("I",), ("F",)):
                pixels = np.asarray(image.convert("L"), dtype=float)
            else:
                pixels = np.asarray(image.convert("RGB"), dtype=float).mean(axis=-1)
    except (OSError, UnidentifiedImageError) as error:
        raise ValueError(f"cannot read map image {path}: {error}; give a PNG or PGM file") from None
    except Image.DecompressionBombError as error:
        raise ValueError(f"map image {path}: {error}; give a smaller image") from None
    return pixels


def _occupancy(grey: np.ndarray) -> np.ndarray:
    """ROS occupancy probability p = (255 - value) / 255."""
    return (255.0 - grey) / 255.0


def _read_npy(path: Path) -> np.ndarray:
    """The 2-D array of a .npy file, its shape and item size checked from the header first."""
    try:
        with open(path, "rb") as fh:
            version = np.lib.format.read_magic(fh)
            read = np.lib.format.read_array_header_1_0 if version == (1, 0) \
                else np.lib.format.read_array_header_2_0
            shape, _, dtype = read(fh)
    except (OSError, ValueError) as error:
        raise ValueError(f"cannot read {path} as a NumPy array: {error}; "
                         "save it with np.save") from None
    if len(shape) != 2:
        raise ValueError(f"{path} holds an array of shape {shape}; a map needs a 2-D array")
    check_cells(path, *shape, dtype.itemsize)
    try:
        return np.load(path, allow_pickle=False)
    except (OSError, ValueError) as error:
        raise ValueError(f"cannot read {path} as a NumPy array: {error}; "
                         "save it with np.save") from None


def _read_movingai(path: Path) -> np.ndarray:
    """MovingAI grid as bool (rows, cols), True = blocked, row 0 = the file's first (top) row.
    The header is read, and the size checked, before the grid."""
    header = {}
    with open(path, encoding="ascii", errors="replace") as fh:
        # Header lines are short: a longer one is read no further than this.
        for number, line in enumerate(iter(lambda: fh.readline(256), "")):
            words = line.split()
            if words == ["map"]:
                break
            if len(words) != 2 or len(line) == 256:
                raise ValueError(f"{path}:{number + 1}: bad MovingAI header line "
                                 f"{line[:80].rstrip()!r}; expected 'type octile', 'height H', "
                                 "'width W', then 'map'")
            header[words[0]] = words[1]
        else:
            raise ValueError(f"{path}: no 'map' line; a MovingAI file has 'type', 'height', "
                             "'width' lines, then 'map', then the grid")
        try:
            rows, cols = int(header["height"]), int(header["width"])
        except (KeyError, ValueError):
            raise ValueError(f"{path}: the header needs integer 'height' and 'width' lines, "
                             f"got {header}") from None
        if rows < 1 or cols < 1:
            raise ValueError(f"{path}: height and width must be >= 1, got {rows} x {cols}")
        check_cells(path, rows, cols, DECODE_BYTES["movingai"])
        # A grid line is cols characters and a line end: twice that bounds what is read, and
        # a line's trailing blanks; more than that is refused below, unread.
        text = fh.read(2 * rows * (cols + 2) + 64)
        if fh.read(4096).strip():
            raise ValueError(f"{path}: the grid is longer than the {rows} rows of {cols} "
                             "characters the header says; fix the header or the grid")
    grid = [line.rstrip() for line in text.splitlines()]
    while grid and not grid[-1]:
        grid.pop()
    if len(grid) != rows or any(len(line) != cols for line in grid):
        raise ValueError(f"{path}: the grid is not {rows} rows of {cols} characters as the header "
                         "says; fix the header or the grid")
    cells = np.array([list(line) for line in grid])
    unknown = set(np.unique(cells)) - _MOVINGAI_FREE - _MOVINGAI_BLOCKED
    if unknown:
        raise ValueError(f"{path}: unknown map characters {sorted(unknown)}; MovingAI uses "
                         "'.', 'G', 'S' (free) and '@', 'O', 'T', 'W' (blocked)")
    return np.isin(cells, list(_MOVINGAI_BLOCKED))


def _plain_loader():
    """PyYAML's safe loader without aliases (`*name`): a ROS map yaml has none, and nested
    aliases expand exponentially (a "billion laughs" file of a few hundred bytes)."""
    import yaml

    class PlainLoader(yaml.SafeLoader):
        def compose_node(self, parent, index):
            if self.check_event(yaml.AliasEvent):
                event = self.peek_event()
                raise yaml.YAMLError(f"an alias (*{event.anchor}) at line "
                                     f"{event.start_mark.line + 1}; a ROS map yaml needs none, "
                                     "write the value out")
            return super().compose_node(parent, index)
    return PlainLoader


def _load_ros(path: Path, expected_resolution) -> OccupancyMap:
    """ROS map_server yaml + image; cells neither free nor occupied count as obstacles."""
    import yaml
    if path.stat().st_size > ROS_YAML_MAX_BYTES:
        raise ValueError(f"{path} holds {path.stat().st_size} bytes; a ROS map yaml is a few "
                         f"lines (at most {ROS_YAML_MAX_BYTES} bytes here): give the map's yaml")
    try:
        meta = yaml.load(path.read_text(), Loader=_plain_loader())
    except (yaml.YAMLError, RecursionError) as error:
        reason = "nested too deeply" if isinstance(error, RecursionError) else error
        reason = str(reason).replace("\n", " ")
        raise ValueError(f"{path} is not valid YAML ({reason}); fix the file") from None
    if not isinstance(meta, dict):
        raise ValueError(f"{path} must be a YAML mapping with image, resolution, origin, "
                         "occupied_thresh, free_thresh")
    missing = [k for k in ("image", "resolution", "origin", "occupied_thresh", "free_thresh")
               if k not in meta]
    if missing:
        raise ValueError(f"{path} lacks {', '.join(missing)}; a ROS map yaml needs image, "
                         "resolution, origin, occupied_thresh and free_thresh")
    resolution = _positive(meta["resolution"], f"resolution in {path.name}")
    if expected_resolution is not None and expected_resolution != resolution:
        raise ValueError(f"{path} says resolution {resolution} but {expected_resolution} was "
                         "given; drop the cell size argument for ROS maps")
    origin = meta["origin"]
    if (not isinstance(origin, list) or len(origin) not in (2, 3)
            or not all(isinstance(v, (int, float)) for v in origin)):
        raise ValueError(f"{path}: origin must be [x, y, yaw], got {origin!r}")
    if len(origin) == 3 and origin[2] != 0:
        # Our grid is axis-aligned; silently dropping the yaw would misplace every obstacle.
        raise ValueError(f"{path}: rotated maps (origin yaw {origin[2]}) are not supported; "
                         "rotate the image and set yaw to 0")
    try:
        occupied_thresh, free_thresh = float(meta["occupied_thresh"]), float(meta["free_thresh"])
    except (TypeError, ValueError):
        raise ValueError(f"{path}: occupied_thresh and free_thresh must be numbers") from None
    if not 0.0 <= free_thresh <= occupied_thresh <= 1.0:
        raise ValueError(f"{path}: need 0 <= free_thresh <= occupied_thresh <= 1, got "
                         f"{free_thresh} and {occupied_thresh}")
    mode = str(meta.get("mode", "trinary")).lower()
    if mode not in _ROS_MODES:
        raise ValueError(f"{path}: unknown mode {mode!r}; use one of {', '.join(_ROS_MODES)}")
    negate = meta.get("negate", 0)
    if negate not in (0, 1, True, False):
        raise ValueError(f"{path}: negate must be 0 or 1, got {negate!r}")
    image = path.parent / str(meta["image"])
    if not image.is_file():
        raise ValueError(f"{path} names image {meta['image']!r}, not found at {image}; fix 'image'")
    grey = _read_grey(image)
    if negate:
        grey = 255.0 - grey
    if mode == "raw":
        # Raw pixels are occupancy percentages; anything above 100 is ROS's "unknown".
        value = np.rint(grey)
        p = np.where(value <= 100.0, value / 100.0, np.nan)
    else:
        p = _occupancy(grey)
    # Trinary and scale differ only for cells between the thresholds (unknown vs. a
    # probability); both are obstacles here, so only the free test matters.
    free = p < free_thresh
    return from_array(~free[::-1], resolution, (float(origin[0]), float(origin[1])))

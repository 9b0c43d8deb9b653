"""Occupancy maps: clearance bounds the true distance, each format lands the right way up."""

import json
import struct
import tracemalloc
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from stepzoo import validate
from stepzoo.cli import main as stepzoo
from stepzoo.errors import UsageError
from stepzoo.search.world.maps import (MAP_BYTES_PER_CELL, MAP_DIR, OccupancyMap, from_array,
                                       load_map)



def true_clearance(occupied, resolution, origin, xy):
    """Brute force: distance [m] from each point to the nearest occupied square or the outside."""
    rows, cols = occupied.shape
    x = (xy[:, 0] - origin[0]) / resolution
    y = (xy[:, 1] - origin[1]) / resolution
    border = np.minimum.reduce([x, cols - x, y, rows - y])
    best = border
    for i, j in np.argwhere(occupied):
        dx = np.maximum.reduce([j - x, x - (j + 1), np.zeros_like(x)])
        dy = np.maximum.reduce([i - y, y - (i + 1), np.zeros_like(y)])
        best = np.minimum(best, np.hypot(dx, dy))
    return best * resolution


def test_clearance_to_a_single_cell_is_a_lower_bound_within_one_cell():
    occupied = np.zeros((21, 21), bool)
    occupied[10, 10] = True
    res, origin = 0.5, (-3.0, 2.0)
    omap = from_array(occupied, res, origin)
    xy = np.random.default_rng(1).uniform([-3, 2], [-3 + 10.5, 2 + 10.5], (4000, 2))
    truth = true_clearance(occupied, res, origin, xy)
    got = omap.clearance(xy)
    assert np.all(got <= truth + 1e-12)
    assert np.all(got >= truth - res)
    # The occupied square itself spans x in [2, 2.5], y in [7, 7.5].
    assert omap.clearance(np.array([2.25, 7.25])) <= 0
    assert omap.clearance(np.array([2.25, 8.5])) == pytest.approx(1.0)


def test_clearance_on_a_random_grid_never_exceeds_the_brute_force_distance():
    rng = np.random.default_rng(7)
    occupied = rng.random((12, 17)) < 0.15
    res, origin = 0.2, (1.0, -1.0)
    omap = from_array(occupied, res, origin)
    xmin, xmax, ymin, ymax = omap.bounds()
    xy = rng.uniform([xmin, ymin], [xmax, ymax], (5000, 2))
    truth = true_clearance(occupied, res, origin, xy)
    got = omap.clearance(xy)
    assert np.all(got <= truth + 1e-12)
    assert np.all(got >= truth - res)
    assert np.array_equal(omap.is_free(xy), got > 0)
    assert not np.any(omap.is_free(xy[truth <= 0]))


@pytest.mark.parametrize("res", [3.0, 1.5, 0.5])
def test_disc_hits_is_the_brute_force_distance_within_the_radius(res):
    # Coarse cells, where the lattice bound is loosest: a 1.2 m disc in a 3 m door.
    rng = np.random.default_rng(11)
    occupied = rng.random((14, 12)) < 0.25
    origin = (2.0, -1.0)
    omap = from_array(occupied, res, origin)
    xmin, xmax, ymin, ymax = omap.bounds()
    xy = rng.uniform([xmin - 2, ymin - 2], [xmax + 2, ymax + 2], (6000, 2))
    truth = np.where(
        (xy[:, 0] < xmin) | (xy[:, 0] > xmax) | (xy[:, 1] < ymin) | (xy[:, 1] > ymax), 0.0,
        true_clearance(occupied, res, origin, xy))
    hits = omap.disc_hits(xy[:, 0], xy[:, 1], 1.2)
    assert np.array_equal(hits, truth <= 1.2)
    # Where the exact answer differs from the lattice bound's, the bound was too cautious.
    bound = omap.clearance(xy) <= 1.2
    assert np.all(bound >= hits)
    assert res < 1.5 or np.any(bound & ~hits)
    assert omap.disc_hits(np.array([np.nan, 1e300]), np.array([0.0, 0.0]), 1.2).all()


def test_the_border_and_everything_off_the_map_are_obstacles():
    omap = from_array(np.zeros((10, 10), bool), 1.0)
    assert omap.bounds() == (0.0, 10.0, 0.0, 10.0)
    # All cells free, yet the clearance is capped by the distance to the edge.
    assert omap.clearance(np.array([5.0, 5.0])) == pytest.approx(5.0)
    assert omap.clearance(np.array([0.5, 5.0])) <= 0.5
    off = np.array([[-0.1, 5.0], [10.1, 5.0], [5.0, -3.0], [5.0, 10.0], [50.0, 50.0]])
    assert np.all(omap.clearance(off) <= 0)
    assert not np.any(omap.is_free(off))


def test_non_finite_points_are_not_free():
    omap = from_array(np.zeros((4, 4), bool), 1.0)
    xy = np.array([[np.nan, 2.0], [2.0, np.inf], [2.0, 2.0]])
    assert omap.is_free(xy).tolist() == [False, False, True]


def test_array_row_zero_is_the_bottom_of_the_world():
    occupied = np.zeros((5, 3), bool)
    occupied[0, 2] = True
    omap = from_array(occupied, 2.0, (10.0, 20.0))
    assert not omap.is_free(np.array([15.0, 21.0]))  # bottom-right cell
    assert omap.is_free(np.array([13.0, 27.0]))


def write_movingai(path, rows):
    path.write_text(f"type octile\nheight {len(rows)}\nwidth {len(rows[0])}\nmap\n"
                    + "\n".join(rows) + "\n")
    return path


def test_movingai_top_row_of_the_file_lands_at_the_top_of_the_world(tmp_path):
    rows = ["....T.",
            "......",
            "......",
            "......",
            "......"]
    omap = load_map(write_movingai(tmp_path / "m.map", rows), cell_size=0.5)
    assert omap.occupied.shape == (5, 6)
    assert omap.bounds() == (0.0, 3.0, 0.0, 2.5)
    assert omap.occupied[4, 4] and omap.occupied.sum() == 1
    assert omap.clearance(np.array([2.25, 2.25])) <= 0  # the T, near y = 2.5
    assert omap.is_free(np.array([2.25, 0.75]))


def test_movingai_characters_follow_the_benchmark_legend(tmp_path):
    omap = load_map(write_movingai(tmp_path / "m.map", [".GS@OTW"]), cell_size=1.0)
    assert omap.occupied[0].tolist() == [False, False, False, True, True, True, True]


@pytest.mark.parametrize("text, complaint", [
    ("type octile\nheight 2\nwidth 3\n", "no 'map' line"),
    ("type octile\nheight two\nwidth 3\nmap\n...\n...\n", "height"),
    ("type octile\nheight 3\nwidth 3\nmap\n...\n...\n", "not 3 rows"),
    ("type octile\nheight 2\nwidth 3\nmap\n...\n..x\n", "unknown map characters"),
    ("type octile\nheight 2 rows\nwidth 3\nmap\n...\n...\n", "bad MovingAI header"),
])
def test_malformed_movingai_files_raise_one_clear_line(tmp_path, text, complaint):
    path = tmp_path / "bad.map"
    path.write_text(text)
    with pytest.raises(ValueError, match=complaint) as error:
        load_map(path, cell_size=1.0)
    assert "\n" not in str(error.value)


def write_ros(tmp_path, pixels, **meta):
    """A PGM (row 0 = top of the image) plus its yaml; returns the yaml path."""
    Image.fromarray(np.asarray(pixels, np.uint8)).save(tmp_path / "map.pgm")
    fields = {"image": "map.pgm", "resolution": 0.1, "origin": [0.0, 0.0, 0.0], "negate": 0,
              "occupied_thresh": 0.65, "free_thresh": 0.25} | meta
    lines = [f"{key}: {value}" for key, value in fields.items()]
    path = tmp_path / "map.yaml"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_ros_origin_shifts_the_world_and_the_image_top_is_up(tmp_path):
    pixels = np.full((4, 6), 254)
    pixels[0, 1] = 0  # top row of the image
    omap = load_map(write_ros(tmp_path, pixels, origin=[-2.0, 3.0, 0.0]))
    assert omap.resolution == 0.1 and omap.origin == (-2.0, 3.0)
    assert omap.bounds() == pytest.approx((-2.0, -1.4, 3.0, 3.4))
    assert omap.occupied[3, 1] and omap.occupied.sum() == 1
    assert omap.clearance(np.array([-1.85, 3.35])) <= 0
    assert omap.clearance(np.array([-1.85, 3.15])) > 0


# Pixel values and their occupancy p = (255 - v) / 255: 0 -> 1, 90 -> 0.65, 128 -> 0.50,
# 205 -> 0.196, 240 -> 0.06, 255 -> 0.
VALUES = [0, 90, 128, 205, 240, 255]


@pytest.mark.parametrize("meta, blocked", [
    ({}, [True, True, True, False, False, False]),
    ({"mode": "scale"}, [True, True, True, False, False, False]),
    ({"free_thresh": 0.1}, [True, True, True, True, False, False]),
    ({"free_thresh": 0.05, "occupied_thresh": 0.1}, [True, True, True, True, True, False]),
    # Negated: p = v / 255, so 0 -> 0 and 255 -> 1.
    ({"negate": 1}, [False, True, True, True, True, True]),
])
def test_ros_thresholds_negate_and_modes_give_the_expected_cells(tmp_path, meta, blocked):
    omap = load_map(write_ros(tmp_path, [VALUES], **meta))
    assert omap.occupied[0].tolist() == blocked


def test_ros_raw_mode_reads_pixels_as_occupancy_percent(tmp_path):
    # 0 % and 20 % are below free_thresh 0.25; 50 % is between; 100 % occupied; 255 unknown.
    omap = load_map(write_ros(tmp_path, [[0, 20, 50, 100, 255]], mode="raw"))
    assert omap.occupied[0].tolist() == [False, False, True, True, True]


@pytest.mark.parametrize("meta, complaint", [
    ({"mode": "fancy"}, "unknown mode"),
    ({"origin": [0.0, 0.0, 0.5]}, "rotated"),
    ({"resolution": -1}, "resolution"),
    ({"image": "nowhere.pgm"}, "not found"),
    ({"free_thresh": 0.9}, "free_thresh"),
])
def test_bad_ros_yaml_raises_one_clear_line(tmp_path, meta, complaint):
    path = write_ros(tmp_path, [[0, 255]], **meta)
    with pytest.raises(ValueError, match=complaint) as error:
        load_map(path)
    assert "\n" not in str(error.value)


def test_malformed_yaml_and_missing_keys_raise(tmp_path):
    broken = tmp_path / "broken.yaml"
    broken.write_text("image: [unclosed\n")
    with pytest.raises(ValueError, match="not valid YAML") as error:
        load_map(broken)
    assert "\n" not in str(error.value)
    partial = tmp_path / "partial.yaml"
    partial.write_text("image: map.pgm\nresolution: 0.1\n")
    with pytest.raises(ValueError, match="origin, occupied_thresh, free_thresh"):
        load_map(partial)


def test_plain_image_dark_is_occupied_and_top_is_up(tmp_path):
    pixels = np.full((3, 4, 3), 255, np.uint8)
    pixels[0, 3] = (20, 20, 20)
    pixels[2, 0] = (200, 200, 200)  # light grey: free
    Image.fromarray(pixels).save(tmp_path / "m.png")
    omap = load_map(tmp_path / "m.png", resolution=0.5)
    expected = np.zeros((3, 4), bool)
    expected[2, 3] = True
    assert np.array_equal(omap.occupied, expected)


def test_npy_arrays_load_with_row_zero_at_the_bottom(tmp_path):
    grid = np.zeros((3, 3), np.uint8)
    grid[0, 0] = 1
    np.save(tmp_path / "g.npy", grid)
    omap = load_map(tmp_path / "g.npy", resolution=1.0)
    assert np.array_equal(omap.occupied, grid.astype(bool))


@pytest.mark.parametrize("name, kwargs, complaint", [
    ("missing.map", {"cell_size": 1.0}, "not found"),
    ("m.txt", {}, "unknown map format"),
    ("m.map", {}, "cell size"),
    ("m.png", {}, "cell size"),
    ("m.npy", {}, "cell size"),
    ("m.map", {"cell_size": 0.0}, "cell_size"),
    ("m.map", {"cell_size": 1.0, "resolution": 2.0}, "disagree"),
])
def test_bad_load_requests_raise_one_clear_line(tmp_path, name, kwargs, complaint):
    write_movingai(tmp_path / "m.map", ["..", ".."])
    (tmp_path / "m.txt").write_text("..\n")
    Image.fromarray(np.full((2, 2), 255, np.uint8)).save(tmp_path / "m.png")
    np.save(tmp_path / "m.npy", np.zeros((2, 2)))
    with pytest.raises(ValueError, match=complaint) as error:
        load_map(tmp_path / name, **kwargs)
    assert "\n" not in str(error.value)


def test_grid_and_parameters_are_validated():
    with pytest.raises(ValueError, match="2-D"):
        from_array(np.zeros(5), 1.0)
    with pytest.raises(ValueError, match="resolution"):
        from_array(np.zeros((2, 2)), float("nan"))
    with pytest.raises(ValueError, match="origin"):
        OccupancyMap(np.zeros((2, 2), bool), 1.0, (0.0,))


MAP_FILES = sorted(p for p in MAP_DIR.iterdir() if p.suffix in (".map", ".yaml"))


def test_the_shared_map_folder_is_covered():
    assert {p.name for p in MAP_FILES} >= {"Berlin_1_256.map", "Boston_0_256.map", "den312d.map",
                                          "room-64-64-8.map", "kurzer_map_parking_lot.yaml",
                                          "nav2_depot.yaml"}


@pytest.mark.parametrize("path", MAP_FILES, ids=lambda p: p.name)
def test_every_shared_map_loads_with_plausible_size_and_free_space(path):
    omap = load_map(path, cell_size=1.0 if path.suffix == ".map" else None)
    rows, cols = omap.occupied.shape
    assert 40 <= rows <= 1000 and 40 <= cols <= 1000
    assert 0.3 < 1.0 - omap.occupied.mean() < 0.99
    xmin, xmax, ymin, ymax = omap.bounds()
    centres = np.stack(np.meshgrid(xmin + (np.arange(cols) + 0.5) * omap.resolution,
                                   ymin + (np.arange(rows) + 0.5) * omap.resolution), -1)
    # Cell centres are free exactly where the grid says so.
    assert np.array_equal(omap.is_free(centres), ~omap.occupied)


def test_a_grid_seen_before_reuses_its_distance_field_and_a_changed_one_gets_its_own(tmp_path):
    """A server plans on the same map file again and again: the field is transformed once,
    and a file changed in between (same name, same size) never gets the old field."""
    from stepzoo.search.world.maps import _grid_distance
    grid = np.zeros((30, 40), bool)
    grid[10:20, 15:25] = True
    np.save(tmp_path / "site.npy", grid)
    first = load_map(tmp_path / "site.npy", cell_size=0.5)
    hits = _grid_distance.cache_info().hits
    again = load_map(tmp_path / "site.npy", cell_size=0.25)
    assert _grid_distance.cache_info().hits == hits + 1
    np.testing.assert_array_equal(again.distance, first.distance / 2)   # same cells, half size
    grid[0, 0] = True
    np.save(tmp_path / "site.npy", grid)
    changed = load_map(tmp_path / "site.npy", cell_size=0.5)
    assert changed.distance[1, 1] == 0 and first.distance[1, 1] > 0      # cell (0, 0)
    xy = np.array([[0.3, 0.3], [1.0, 0.8], [12.0, 4.0]])
    assert np.all(changed.clearance(xy) <= true_clearance(grid, 0.5, (0.0, 0.0), xy) + 1e-12)


def png_header(rows: int, cols: int) -> bytes:
    """A PNG that is its signature and IHDR chunk alone: the size, no pixels."""
    data = struct.pack(">IIBBBBB", cols, rows, 8, 0, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + struct.pack(">I", len(data)) + b"IHDR" + data
            + struct.pack(">I", zlib.crc32(b"IHDR" + data)))


def huge_maps(folder: Path) -> dict:
    """20000 x 20000 cells in each format, none of them taking its size on disk: a sparse
    .npy (its data a hole), headers without pixels, a MovingAI header without its grid."""
    with open(folder / "big.npy", "wb") as fh:
        np.lib.format.write_array_header_1_0(fh, {"descr": "|b1", "fortran_order": False,
                                                  "shape": (20000, 20000)})
        fh.truncate(fh.tell() + 20000 * 20000)
    (folder / "big.png").write_bytes(png_header(20000, 20000))
    (folder / "big.pgm").write_bytes(b"P5\n# a comment\n20000 20000\n255\n")
    (folder / "big.map").write_text("type octile\nheight 20000\nwidth 20000\nmap\n")
    ros = folder / "big.yaml"
    ros.write_text("image: big.png\nresolution: 0.05\norigin: [0.0, 0.0, 0.0]\n"
                   "occupied_thresh: 0.65\nfree_thresh: 0.196\n")
    return {p.suffix: p for p in folder.iterdir()}


@pytest.mark.parametrize("suffix", [".npy", ".png", ".pgm", ".map", ".yaml"])
def test_a_map_past_the_memory_limit_is_refused_from_its_header_alone(tmp_path, monkeypatch,
                                                                      suffix):
    """20000 x 20000 cells need tens of GiB to build: refused with the size and the flag
    that raises the limit, having allocated next to nothing (tracemalloc sees NumPy's)."""
    monkeypatch.setattr(validate, "BUDGET", validate.Budget(memory=4 * validate.GIB))
    path = huge_maps(tmp_path)[suffix]
    tracemalloc.start()
    try:
        with pytest.raises(UsageError) as error:
            load_map(path, cell_size=None if suffix == ".yaml" else 0.1)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    message = str(error.value)
    assert "20000 x 20000 cells" in message and "--max-memory" in message
    assert "past the limit of 4 GiB" in message and "\n" not in message
    assert peak < 1e6, peak


def test_the_memory_limit_counts_cells_times_bytes_per_cell(tmp_path, monkeypatch):
    """A map just under the limit loads; the same map just over it is refused."""
    np.save(tmp_path / "m.npy", np.zeros((40, 50), np.uint8))
    need = 40 * 50 * (MAP_BYTES_PER_CELL + 1)
    monkeypatch.setattr(validate, "BUDGET", validate.Budget(memory=need))
    assert load_map(tmp_path / "m.npy", cell_size=1.0).occupied.shape == (40, 50)
    monkeypatch.setattr(validate, "BUDGET", validate.Budget(memory=need - 1))
    with pytest.raises(UsageError, match="40 x 50 cells"):
        load_map(tmp_path / "m.npy", cell_size=1.0)


def test_a_huge_map_on_the_command_line_is_one_line_and_exit_2(tmp_path, capsys):
    path = huge_maps(tmp_path)[".npy"]
    assert stepzoo(["plan", "--map", str(path), "--cell-size", "0.1", "--start", "1,1,0",
                    "--goal", "5,5,0", "--out", str(tmp_path / "out"), "--max-memory", "2"]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err.count("\n") == 1, captured.err
    assert "20000 x 20000 cells" in captured.err and "--max-memory" in captured.err
    assert not (tmp_path / "out").exists()


def test_plan_bench_refuses_a_huge_map_naming_the_flag_it_takes(tmp_path, capsys):
    """plan-bench loads maps too: the refusal's --max-memory is a flag it accepts."""
    huge_maps(tmp_path)
    queries = tmp_path / "q.json"
    queries.write_text(json.dumps([{"map": "big.npy", "cell_size": 0.1, "start": [1, 1, 0],
                                    "goal": [5, 5, 0]}]))
    assert stepzoo(["plan-bench", str(queries), "--out", str(tmp_path / "out"),
                    "--max-memory", "2"]) == 2
    captured = capsys.readouterr()
    assert captured.err.count("\n") == 1, captured.err
    assert "20000 x 20000 cells" in captured.err and "--max-memory" in captured.err
    assert not (tmp_path / "out").exists()


BOMB = "".join(f"{b}: &{b} [{', '.join([f'*{a}'] * 9)}]\n"
               for a, b in zip("abcdefgh", "bcdefghi"))


ROS_KEYS = "image: m.pgm\nresolution: 0.1\noccupied_thresh: 0.65\nfree_thresh: 0.2\n"


def test_a_yaml_alias_bomb_is_refused_before_it_expands(tmp_path):
    """Nine levels of nine aliases: 387 million strings once expanded (the origin's repr
    in an error message did expand them, into a MemoryError)."""
    path = tmp_path / "bomb.yaml"
    path.write_text('a: &a ["x", "x", "x", "x", "x", "x", "x", "x", "x"]\n' + BOMB
                    + "origin: *i\n" + ROS_KEYS)
    tracemalloc.start()
    try:
        with pytest.raises(ValueError, match=r"not valid YAML \(an alias \(\*a\) at line 2") \
                as error:
            load_map(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert "\n" not in str(error.value) and peak < 1e6, peak


def test_yaml_nested_past_the_recursion_limit_is_one_line(tmp_path):
    path = tmp_path / "deep.yaml"
    path.write_text("origin: " + "[" * 5000 + "]" * 5000 + "\n" + ROS_KEYS)
    with pytest.raises(ValueError, match=r"not valid YAML \(nested too deeply\)") as error:
        load_map(path)
    assert "\n" not in str(error.value)


def test_a_yaml_file_far_larger_than_a_map_yaml_is_refused_unparsed(tmp_path):
    path = tmp_path / "big.yaml"
    path.write_text("# padding\n" * 10000)
    with pytest.raises(ValueError, match="a ROS map yaml is a few lines"):
        load_map(path)


def test_a_movingai_grid_longer_than_its_header_says_is_refused(tmp_path):
    path = tmp_path / "long.map"
    path.write_text("type octile\nheight 2\nwidth 2\nmap\n..\n..\n" + "..\n" * 5000)
    with pytest.raises(ValueError, match="longer than the 2 rows"):
        load_map(path, cell_size=1.0)

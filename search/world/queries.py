"""Query files for `stepzoo plan-bench`: a JSON list of {map, cell_size, start, goal, id}, the map
path relative to the file (declared in query_file.py); and the seeded generator of random
street queries (start and goal in one free region of a map, a given distance apart, the start
with a collision-free forward departure and the goal with a collision-free forward arrival)
that wrote the shipped test set."""
from __future__ import annotations

import json
import math
import os
import unicodedata
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.ndimage import label

from stepzoo import dynamics
from stepzoo.config_schema import check
from stepzoo.errors import UsageError
from stepzoo.safe_parse import json_loads
from stepzoo.search.proofs.departure import free_departure, turned
from stepzoo.search.world.footprint import Footprint, poses_collide
from stepzoo.search.world.maps import MAP_DIR, SUBDIV, OccupancyMap
from stepzoo.search.world.query_file import QueryFile
from stepzoo.search.planner.config import PlannerParams
from stepzoo.search.world.scenarios import open_map, pose

QUERY_DIR = Path(__file__).with_name("queries")
STREET_QUERIES = QUERY_DIR / "streets.json"
# An id plus ".log" stays within the 255 bytes a file name may have on common file systems.
MAX_ID_BYTES = 200
# The maps of the shipped test set and their cell sizes [m/cell]; 12 queries each, seeds 0..3.
STREET_MAPS = (("Berlin_1_256.map", 1.5), ("Boston_0_256.map", 1.5), ("den312d.map", 1.5),
               ("room-64-64-8.map", 3.0))


@dataclass(frozen=True)
class Query:
    id: str
    map: str                 # as written in the file: relative to it
    map_path: Path           # resolved
    cell_size: float | None  # [m/cell] for formats that do not store it
    start: tuple             # (X, Y, psi) [m, m, rad]
    goal: tuple              # (X, Y, psi) [m, m, rad]


def load_queries(path) -> list[Query]:
    """The queries of a plan-bench file, each checked against its declaration (QueryFile);
    the first mistake is one UsageError line."""
    path = Path(path)
    try:
        data = json_loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise UsageError(f"cannot read queries {path}: {err}") from None
    if not isinstance(data, list) or not data:
        raise UsageError(f"{path} must hold a non-empty JSON list of queries "
                         "{map, cell_size, start, goal, id}")
    queries, seen = [], set()
    for k, item in enumerate(data):
        where = f"{path} query {k}"
        if not isinstance(item, dict) or not {"map", "start", "goal"} <= set(item):
            raise UsageError(f"{where} must be an object with map, start and goal "
                             "(cell_size for MovingAI maps, id optional)")
        try:
            check(QueryFile, item, where)
        except UsageError as err:         # the first mistake, as every other here: one line
            raise UsageError(str(err).splitlines()[0]) from None
        qid = str(item.get("id", k))
        bad = id_problem(qid)
        if bad:
            raise UsageError(f"{where}: id {qid!r} {bad}; an id names the query's files "
                             "(ompl/<id>.log): use letters, digits, '-', '_' and '.'")
        if qid in seen:
            raise UsageError(f"{where}: id {qid!r} appears twice; ids must be unique")
        seen.add(qid)
        cell = item.get("cell_size")
        queries.append(Query(qid, str(item["map"]), path.parent / str(item["map"]),
                             None if cell is None else float(cell),
                             pose(item["start"], f"start of {where}"),
                             pose(item["goal"], f"goal of {where}")))
    return queries


def id_problem(qid: str) -> str | None:
    """Why `qid` cannot name a file inside the output folder (None: it can): a path
    separator, `..` or a leading dot would leave the folder or hide the file, and a NUL or
    control character is refused by the file system or by a terminal."""
    if not qid:
        return "is empty"
    # Unicode's control characters (C0, DEL and C1, such as U+0085, a line break to some
    # readers), surrogates, and the line and paragraph separators.
    if any(unicodedata.category(c) in ("Cc", "Cs", "Zl", "Zp") for c in qid):
        return "holds a NUL or control character"
    if "/" in qid or "\\" in qid:
        return "holds a path separator"
    if qid.startswith("."):
        return "starts with a dot"
    if len(qid.encode()) > MAX_ID_BYTES:
        return f"is longer than {MAX_ID_BYTES} bytes"
    return None


def random_queries(map_path, cell_size, n, seed, *, vehicle=None, margin=0.1, near=30.0,
                   far=300.0, room=2.5, rel_to=None) -> list[dict]:
    """`n` seeded queries on one map: start and goal centres at lattice points with at least
    `room` [m] to the nearest obstacle, in one region of lattice points where the car's centre
    may be (clearance >= half its width + margin), `near`..`far` [m] apart;
    headings uniform; a pair is redrawn if a footprint (+margin) collides, or if no forward
    arc at the steer limit or gentler leaves the start (arrives at the goal) free for
    DEPARTURE_M: a query a forward-only car can at least begin. Map paths are written
    relative to `rel_to` (a folder)."""
    omap = open_map(Path(map_path), cell_size)
    spec = dynamics.vehicle(vehicle)
    length, width = spec["length"] + 2 * margin, spec["width"] + 2 * margin
    # The shipped query sets were drawn with the discs deciding collisions: so they still are.
    footprint = Footprint.from_vehicle(length, width, 2 * math.ceil(length / width),
                                       rectangle=False)
    radius = (spec["Lf"] + spec["Lr"]) / math.tan(PlannerParams().delta_max)
    rng = np.random.default_rng(seed)
    points, region = _roomy_points(omap, room, spec["width"] / 2 + margin)
    name = Path(map_path).stem
    rel = Path(map_path) if rel_to is None else Path(_relative(map_path, rel_to))
    out: list[dict] = []
    while len(out) < n:
        i = rng.integers(len(points))
        a, mates = points[i], points[region == region[i]]
        gap = np.hypot(*(mates - a).T)
        mates = mates[(gap >= near) & (gap <= far)]
        if not len(mates):
            continue
        b = mates[rng.integers(len(mates))]
        start, goal = (np.r_[p, rng.uniform(-math.pi, math.pi)] for p in (a, b))
        if poses_collide(omap, footprint, np.vstack([start, goal])).any() or not (
                free_departure(omap, footprint, start, radius)
                and free_departure(omap, footprint, turned(goal), radius)):
            continue
        out.append({"id": f"{name}-{len(out):02d}", "map": str(rel), "cell_size": cell_size,
                    "start": np.round(start, 3).tolist(), "goal": np.round(goal, 3).tolist()})
    return out


def street_queries(per_map=12) -> list[dict]:
    """The shipped test set (STREET_QUERIES holds it, one query a line)."""
    out = []
    for seed, (name, cell) in enumerate(STREET_MAPS):
        out += random_queries(MAP_DIR / name, cell, per_map, seed, rel_to=QUERY_DIR)
    return out


def _roomy_points(omap: OccupancyMap, room, half_width) -> tuple[np.ndarray, np.ndarray]:
    """(K, 2) [m] lattice points with clearance >= room, and the (K,) label of the
    8-connected region of lattice points with clearance >= half_width [m] each lies in."""
    step = omap.resolution / SUBDIV
    labels = label(omap.distance >= half_width, structure=np.ones((3, 3)))[0]
    rows, cols = np.nonzero(omap.distance >= room)
    points = np.column_stack([cols, rows]) * step + np.asarray(omap.origin)
    return points, labels[rows, cols]


def _relative(path, folder) -> str:
    return os.path.relpath(Path(path).resolve(), Path(folder).resolve())

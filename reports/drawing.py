"""Drawing a report's figures: each figure's data computed once (figure_data), then drawn by
both renderers, the PNG into the report folder and the Plotly figure as a page fragment.
Figures may also be drawn apart (`draw_apart`, e.g. in another process while `stepzoo run`
plans) and handed to `draw_all` as drawn."""
from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import NamedTuple

from stepzoo.output import atomic_write
from stepzoo.reports import figures, interactive


class Drawn(NamedTuple):
    """A figure drawn apart from its report: its Shown record, its Plotly fragments, and its
    PNG files ({name: bytes})."""
    shown: figures.Shown
    divs: list
    files: dict


def _draw(data, into: Path) -> tuple:
    """(Shown, Plotly fragments) of one figure's data, its PNGs written into `into`."""
    fig = figures.draw(data, into)
    return fig, interactive.divs(interactive.draw(data), f"plot{fig.number}")


def draw_apart(computes: list) -> list[Drawn]:
    """The figures whose data the callables `computes` return, in their order, drawn with
    their files kept in memory."""
    drawn = []
    with tempfile.TemporaryDirectory() as tmp:
        for compute in computes:
            fig, divs = _draw(compute(), Path(tmp))
            drawn.append(Drawn(fig, divs, {name: (Path(tmp) / name).read_bytes()
                                           for name, _ in fig.images}))
    return drawn


def draw_all(computes: list, into, say, drawn=()) -> tuple[list, dict]:
    """(Shown records, {figure number: HTML fragments}) of the figures `drawn` (Drawn
    records, whose files are written into `into`) followed by those whose data the callables
    `computes` return, in their order; `say` gets a line per figure."""
    shown, plots = [], {}
    total = len(drawn) + len(computes)

    def record(fig, divs, took: str):
        plots[fig.number] = divs
        shown.append(fig)
        say(f"[{len(shown)}/{total}] Figure {fig.number}. {fig.title}: "
            f"{len(fig.images)} image(s) {took}")

    for fig, divs, files in drawn:
        for name, data in files.items():
            atomic_write(Path(into) / name, data)
        record(fig, divs, "drawn ahead")
    for compute in computes:
        t0 = time.perf_counter()
        fig, divs = _draw(compute(), into)
        record(fig, divs, f"in {time.perf_counter() - t0:.1f} s")
    return shown, plots

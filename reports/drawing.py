"""Drawing a report's figures: each figure's data computed once (figure_data), then drawn by
both renderers, the PNG into the report folder and the Plotly figure as a page fragment."""
from __future__ import annotations

import time

from stepzoo.reports import figures, interactive


def draw_all(computes: list, into, say) -> tuple[list, dict]:
    """(Shown records, {figure number: HTML fragments}) of the figures whose data the
    callables `computes` return, in their order; `say` gets a line per figure."""
    shown, plots = [], {}
    for compute in computes:
        t0 = time.perf_counter()
        data = compute()
        fig = figures.draw(data, into)
        plots[fig.number] = interactive.divs(interactive.draw(data), f"plot{fig.number}")
        shown.append(fig)
        say(f"[{len(shown)}/{len(computes)}] Figure {fig.number}. {fig.title}: "
            f"{len(fig.images)} image(s) in {time.perf_counter() - t0:.1f} s")
    return shown, plots

"""The integrator that plans fastest without straying from its plans: among candidates benched
on the same queries and seeds, the smallest median plan time [s] of those whose exact rate is
the best of all and whose replay deviation stays below a tolerance [m] on every exact plan."""
from __future__ import annotations

from stepzoo.errors import NoAnswer

# What each candidate's evidence records, from plan-bench's summary per integrator.
EVIDENCE = ("integrator", "method", "h", "runs", "exact", "exact_rate", "median_time_s",
            "median_replay_deviation_m", "max_replay_deviation_m", "replay_collisions")


def within(summary: dict, tol_m: float) -> bool:
    """Every exact plan of `summary` replays closer to its plan than `tol_m` [m]."""
    worst = summary.get("max_replay_deviation_m")
    return summary["exact"] > 0 and worst is not None and worst < tol_m


def choose(summaries: list[dict], tol_m: float) -> tuple[int, list[dict]]:
    """(index of the chosen summary, one evidence row per summary with `within_tol` and
    `verdict`: why it won or lost). Equal median times go to the smaller deviation, then to
    the earlier candidate. NoAnswer when no candidate plans exactly or none at the best
    exact rate stays within `tol_m` [m]."""
    best = max(s["exact"] for s in summaries)
    if best == 0:
        raise NoAnswer("no candidate planned any query exactly, so no replay says how far "
                       "the car strays; give queries the planner solves, or a larger budget "
                       "(max_seconds in the config's [planner] table)")
    eligible = [i for i, s in enumerate(summaries) if s["exact"] == best and within(s, tol_m)]
    if not eligible:
        closest = min((s for s in summaries if s["exact"] == best),
                      key=lambda s: s["max_replay_deviation_m"])
        raise NoAnswer(f"no candidate at the best exact rate ({best} of "
                       f"{summaries[0]['runs']}) keeps every replay within {tol_m:g} m of its "
                       f"plan: the closest is {closest['integrator']}, "
                       f"{closest['max_replay_deviation_m']:.3g} m; loosen --replay-tol")
    won = min(eligible, key=lambda i: (summaries[i]["median_time_s"],
                                       summaries[i]["max_replay_deviation_m"], i))
    t_won = summaries[won]["median_time_s"]
    rows = []
    for i, s in enumerate(summaries):
        ok = within(s, tol_m)
        if i == won:
            verdict = (f"chosen: the smallest median plan time ({t_won:.3g} s) of the "
                       f"{len(eligible)} candidates that planned {best} of {s['runs']} "
                       f"exactly, the best rate, and replay within {tol_m:g} m of every "
                       "exact plan")
        elif s["exact"] < best:
            verdict = f"planned {s['exact']} of {s['runs']} exactly, fewer than the best {best}"
        elif not ok:
            verdict = (f"a replay strayed {s['max_replay_deviation_m']:.3g} m from its plan, "
                       f"not below {tol_m:g} m")
        else:
            verdict = (f"median plan time {s['median_time_s']:.3g} s, "
                       f"{s['median_time_s'] / t_won:.3g} x the choice's")
        rows.append({**{k: s.get(k) for k in EVIDENCE}, "within_tol": ok,
                     "verdict": verdict})
    return won, rows

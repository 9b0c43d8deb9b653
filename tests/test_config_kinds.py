"""Every config file kind, read by its command: an unknown key is refused in one line (exit
2, nothing written), every mistake of a file is named at once with the range's unit, and a
sweep's sha256 is what its values say, not how the file spells them."""
import json
import sys
import tomllib
from pathlib import Path

import pytest
import tomli_w

from stepzoo.cli import main as stepzoo
from stepzoo.bench.sweep.config import load

ROOT = Path(__file__).resolve().parents[1]
SMALL = ROOT / "bench" / "configs" / "small.toml"
SCENARIO = ROOT / "search" / "world" / "scenarios" / "street.toml"
TUNED = ROOT / "search" / "planner" / "tuned_default.toml"
SUITE = ('methods = ["rk4"]\nhorizon = 1.0\nsteps.h = [0.1]\n'
         '[[problem]]\nmodel = "detest_a1"\n[[problem]]\nmodel = "detest_a2"\n')


def refused(capsys, argv, out=None) -> list[str]:
    """The lines `stepzoo ARGV` prints on stderr when it refuses with exit status 2."""
    assert stepzoo([str(a) for a in argv]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and (out is None or not out.exists())
    return captured.err.strip().splitlines()


def written(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def with_key(source: Path, tmp_path: Path, line: str, table: str | None = None) -> Path:
    """`source` with `line` added at its top level (or at the end of [table])."""
    text = source.read_text()
    text = line + "\n" + text if table is None else text + f"\n[{table}]\n{line}\n"
    return written(tmp_path / source.name, text)


@pytest.mark.parametrize("argv, where", [
    (lambda t: ["sweep", with_key(SMALL, t, "colour = 3"), "--out", t / "out"],
     "unknown key 'colour'"),
    (lambda t: ["sweep", written(t / "suite.toml", SUITE + "colour = 3\n"), "--out",
                t / "out"], "[problem detest_a2]: unknown key 'colour'"),
    (lambda t: ["plan", with_key(SCENARIO, t, "colour = 3"), "--out", t / "out"],
     "unknown key 'colour'"),
    (lambda t: ["plan", "street", "--config", with_key(TUNED, t, "colour = 3"), "--out",
                t / "out"], "tuned_default.toml: unknown key 'colour'"),
    (lambda t: ["export", with_key(TUNED, t, "colour = 3"), "--to", "json", "--out",
                t / "out"], "tuned_default.toml: unknown key 'colour'"),
    (lambda t: ["plan", "street", "--config", written(
        t / "planner.toml", 'method = "rk4"\nh = 0.02\n[planner]\ncolour = 3\n'), "--out",
        t / "out"], "colour"),
    (lambda t: ["plan-bench", written(t / "q.json", json.dumps([
        {"map": "x.npy", "cell_size": 1, "start": [0, 0, 0], "goal": [1, 1, 0], "colour": 3}])),
        "--out", t / "out"], "q.json query 0: unknown key 'colour'"),
], ids=["sweep", "suite", "scenario", "tuned by plan", "tuned by export", "planner", "queries"])
def test_every_kind_refuses_an_unknown_key_in_one_line(tmp_path, capsys, argv, where):
    lines = refused(capsys, argv(tmp_path), tmp_path / "out")
    assert len(lines) == 1 and where in lines[0], lines


def test_plan_bench_and_report_read_a_tuned_file_as_the_tuned_kind(tmp_path, capsys,
                                                                   tiny_sweep):
    """Every reader of a tuned file checks it by the one declaration: plan-bench's
    --integrators-from and the report's --tuned refuse the unknown key as plan does."""
    bad = with_key(TUNED, tmp_path, "colour = 3")
    queries = ROOT / "search" / "world" / "queries" / "streets.json"
    for argv in (["plan-bench", queries, "--integrators-from", bad, "--out", tmp_path / "out"],
                 ["report", tiny_sweep[1], "--tuned", bad, "--out", tmp_path / "out"]):
        lines = refused(capsys, argv, tmp_path / "out")
        assert len(lines) == 1 and "tuned_default.toml: unknown key 'colour'" in lines[0], lines


def test_a_sweep_config_names_every_mistake_at_once_with_the_unit(tmp_path, capsys):
    raw = tomllib.loads(SMALL.read_text())
    raw["stability"]["h_probe_max"] = 500.0
    raw["stability"]["steps"] = 10
    raw["chunks"]["point"] = 9
    raw["reference"]["solver"] = "rk45"
    path = written(tmp_path / "bad.toml", tomli_w.dumps(raw))
    lines = refused(capsys, ["sweep", path, "--out", tmp_path / "out"], tmp_path / "out")
    assert len(lines) == 4, lines
    text = "\n".join(lines)
    assert "stability.h_probe_max must be a step size: a number in [1e-09, 100] s (" in text
    assert "stability.steps must be a whole number in [50, 100000]" in text
    assert "unknown key chunks.point; known: points (did you mean points?)" in text
    assert "reference.solver must be one of '', 'dopri5', 'LSODA'" in text


def test_a_default_written_out_keeps_the_sweep_sha256_and_a_change_moves_it(tmp_path):
    plain = load(SMALL)
    raw = tomllib.loads(SMALL.read_text())
    raw["timing"] = {"rounds": 5}
    raw["newton"] = {"rtol": 1e-10, "max_iter": 10}
    raw["reference"].update(solver="dopri5", exact=False)
    raw["error"] = {"estimate": "max", "states": ["vy", "r"], "scales": [1.0, 1.0]}
    raw["limits"] = {"memory_gib": 64.0}            # decides no result
    raw["steps"]["h"] = {"values": list(plain.hs)}  # the same steps, written out
    spelled = load(written(tmp_path / "spelled.toml", tomli_w.dumps(raw)))
    assert spelled.sha256 == plain.sha256 and spelled == plain
    raw["timing"]["rounds"] = 4
    assert load(written(tmp_path / "other.toml", tomli_w.dumps(raw))).sha256 != plain.sha256


def test_an_empty_file_is_one_line_naming_what_its_kind_needs(tmp_path, capsys):
    """The second battery's case: an empty config named two missing keys on two lines; the
    file is one mistake."""
    empty = written(tmp_path / "empty.toml", "")
    out = tmp_path / "out"
    for argv, words in ((["sweep", empty, "--out", out], "a sweep config needs at least "
                         "horizon and steps"),
                        (["plan", "street", "--config", empty, "--out", out],
                         "a tuned config needs at least method and h")):
        lines = refused(capsys, argv, out)
        assert lines == [f"stepzoo {argv[0]}: error: {empty}: is empty; {words}"]


def test_a_planner_value_of_no_accepted_type_is_one_line(tmp_path, capsys):
    """A [planner] value may be a number, a whole number or a switch: a string fits none,
    which was one line per type it might have been."""
    config = written(tmp_path / "planner.toml",
                     'method = "rk4"\nh = 0.02\n[planner]\nmax_seconds = "ten"\n')
    lines = refused(capsys, ["plan", "street", "--config", config, "--out", tmp_path / "out"],
                    tmp_path / "out")
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"stepzoo plan: error: {config}") and \
        "max_seconds must be" in lines[0] and lines[0].endswith("got 'ten'"), lines


def test_a_config_of_another_kind_is_one_line_naming_its_kind(tmp_path, capsys, tiny_sweep):
    """A sweep config given where a tuned config belongs (--tuned, --integrators-from,
    --config) lacked method and h and had eleven unknown keys: fourteen lines."""
    queries = ROOT / "search" / "world" / "queries" / "streets.json"
    out = tmp_path / "out"
    for argv in (["plan", "street", "--config", SMALL, "--out", out],
                 ["plan-bench", queries, "--integrators-from", SMALL, "--out", out],
                 ["report", tiny_sweep[1], "--tuned", SMALL, "--out", out]):
        lines = refused(capsys, argv, out)
        assert len(lines) == 1, lines
        assert (f"{SMALL}: is a sweep config, not a tuned config (it has chunks, envelope, "
                "horizon and 8 more keys and lacks method, h); give a tuned config") \
            in lines[0]


# The sha256 of every sweep config of the repository (of a suite: over its problems' own), as
# the results folders swept from them record it: the config's declaration may change shape,
# its fingerprint may not (tune, export and --resume find a folder's sweep again by it).
RECORDED_SHA256 = {
    "bench/configs/detest.toml":
        "f883f784bdebe6e473277953941d2c8b23e1b818f9729b8677699e491da5693e",
    "bench/configs/envelope.toml":
        "548418adc76d0e02754e6bc56cb40da6eed03094195c4e66c70d9c367031dba5",
    "bench/configs/paper.toml":
        "cc3eae8fb8a41ca2c60043d7aa5ce6277d9caf2078085a4a2af10f4a656d6873",
    "bench/configs/small.toml":
        "817b9d0908d9175a08d90234a1777b302e2bac78c25c19f296f16c7dd6fe7149",
    "bench/configs/stiff.toml":
        "4d2f2b66af0abeb8f6d2908592c1b7791490da2093774746b885c1575aa9401c",
    "bench/configs/stiff9.toml":
        "4cc0ae1231b7a11d66b85e4bef05298b463f0c6a3d2e44c111565fa8c32816ba",
    "bench/configs/tyre_laws.toml":
        "24fe6817b12d3e9f29eb527c47b7b420fbf9be84742b63953d6a58ad1067d3d7",
    "bench/configs/tyres.toml":
        "af0b2865a9cb3298f77b8961c0df206886c6701f4b9fe0a8d5957befc8076ac5",
    "bench/configs/wheel.toml":
        "73c2628bb44bc679a1aa3a88977da142a5063b4097ec3d0a20f83a0e55bbb7c8",
    "docs/examples/myvehicle/vehicle.toml":
        "f58edd0e2790a30757dd3856679e0c3bacb218a778e3c286f284eed7a7e64d79",
    "docs/examples/myvehicle/vehicle_casadi.toml":
        "739570f587bb07f8d013617e8f3b74196b91feb5eaacc5818b0ebad363affdc0",
    "tests/data/sweep_regression/suite.toml":
        "d18987808a9d116141c98cfa32464e573468299fea08534a1a2247df6e28937b",
    "tests/user_model/casadi_bicycle.toml":
        "51335bb0b60fea949f100586b97bb69e8e36586a2156d706a84f10a791c44fec",
    "tests/user_model/chain.toml":
        "88a3f4bed648e3b3ea89350efc915c8a2f2d0c7958566328bb375b563129885a",
    "tests/user_model/quarter_wheel.toml":
        "64af15128a456546e0133dc7d9e8fe494dc078123db3ec78b0cbfde787b76116",
    "tests/user_model/steer_clamp.toml":
        "2bb7cdf2ba11e1e1a78be05c8591384d503d4e07504e0853d2ebbd84605d6a98",
}


@pytest.mark.parametrize("name", sorted(RECORDED_SHA256))
def test_the_repositorys_sweep_configs_keep_their_recorded_sha256(name, monkeypatch):
    from stepzoo.bench.sweep.suite import load as load_any
    # Another test in this process may have imported a copy of the docs example's model
    # module from its own folder; the loader would rightly call this one shadowed.
    for module in ("vehicle", "vehicle_casadi"):
        monkeypatch.delitem(sys.modules, module, raising=False)
    assert load_any(ROOT / name).sha256 == RECORDED_SHA256[name]


def test_a_tuned_file_is_the_planners_choice_and_tunes_evidence_side_by_side():
    """The tuned kind is two declared parts in one table: what the planner reads and the
    evidence tune chose it by. The file's keys are theirs, each once, in the file's order;
    each part of the shipped file holds its own keys' values."""
    from stepzoo.config_schema import check
    from stepzoo.tuned_file import PlannerChoice, TuneEvidence, TunedFile
    choice, evidence = list(PlannerChoice.model_fields), list(TuneEvidence.model_fields)
    assert not set(choice) & set(evidence) and {"method", "h", "planner"} <= set(choice)
    assert {"runners_up", "sweep_config_sha256", "margin"} <= set(evidence)
    assert list(TunedFile.model_fields) == choice + evidence
    data = tomllib.loads(TUNED.read_text())
    tuned = check(TunedFile, data, str(TUNED))
    assert (tuned.choice.method, tuned.choice.h) == (data["method"], data["h"])
    assert [r.method for r in tuned.evidence.runners_up] == \
        [r["method"] for r in data["runners_up"]]
    assert {**tuned.choice.model_dump(), **tuned.evidence.model_dump()} == tuned.model_dump()


def test_the_planner_reads_a_tuned_files_choice_alone(tmp_path):
    from stepzoo.search.planner.config import load_config
    from stepzoo.tuned_file import PlannerChoice
    data = tomllib.loads(TUNED.read_text())
    alone = written(tmp_path / "choice.toml", tomli_w.dumps(
        {k: data[k] for k in PlannerChoice.model_fields if k in data}))
    full, own = load_config(TUNED), load_config(alone)
    assert (full.method, full.h, full.params, full.provenance) == \
        (own.method, own.h, own.params, own.provenance)


def test_every_setting_of_a_sweep_is_fingerprinted_or_decides_no_result():
    """A key added to a settings table must be given its name in the sha256 (FINGERPRINT):
    else two sweeps that differ in it would share a fingerprint, and resume into one folder."""
    from stepzoo.bench.sweep.config import FINGERPRINT, SweepConfig
    tables = ("reference", "stability", "chunks", "trajectories", "timing", "error", "limits")
    settings = {(t, k) for t in tables
                for k in SweepConfig.model_fields[t].annotation.model_fields}
    in_spec = {("error", "states"), ("error", "scales")}     # the model spec holds them
    decide_nothing = {("limits", "memory_gib"), ("limits", "steps")}
    assert settings - in_spec - decide_nothing == set(FINGERPRINT.values())
    assert len(set(FINGERPRINT.values())) == len(FINGERPRINT)
    base = load(SMALL)
    for table, key in FINGERPRINT.values():     # each one moves it
        value = getattr(getattr(base, table), key)
        other = {bool: lambda v: not v, int: lambda v: v + 1, float: lambda v: v * 0.5,
                 tuple: lambda v: v[:1], str: lambda v: v + "x"}.get(type(value),
                                                                    lambda v: 0.5)(value)
        assert base.changed(**{table: {key: other}}).sha256 != base.sha256, (table, key)

"""The docs say what the code does: every flag `--help` prints, every config key the validator
accepts and every column a sweep writes appear in the generated reference; Getting started
shows the README's example (which test_wheel.py runs) unchanged; the README stays a short
front door; and the site builds with every warning an error and, opened from the file
system, works with the network refused."""
import contextlib
import importlib.util
import io
import re
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

import report_browser

pytest.importorskip("mkdocs", reason="the docs extra is not installed: pip install -e '.[docs]'")

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()


@pytest.fixture(scope="module")
def ref():
    """The generator of the reference pages, as the site's build loads it."""
    spec = importlib.util.spec_from_file_location("reference", ROOT / "docs/gen/reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """The site, built as `make docs` builds it: (its folder, the build's output)."""
    out = tmp_path_factory.mktemp("site")
    done = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir",
                           str(out)], cwd=ROOT, capture_output=True, text=True)
    return out, done


def test_every_flag_that_help_prints_is_in_the_command_reference(ref):
    page = ref.commands_page()
    cli = ref.cli()
    assert list(cli.COMMANDS) == list(ref.command_parsers())
    for name in cli.COMMANDS:
        help_text = io.StringIO()
        with contextlib.redirect_stdout(help_text), pytest.raises(SystemExit):
            cli.build_parser(name).parse_args([name, "--help"])
        listed = re.findall(r"^  (-.*?)(?:\s{2,}|$)", help_text.getvalue(), re.M)
        flags = {f for entry in listed for f in re.findall(r"(?<![\w-])--?[a-zA-Z][\w-]*", entry)}
        assert "--platform" in flags                 # the parse saw the command's own help
        section = page.split(f"## `stepzoo {name}`")[1].split("\n## ")[0]
        missing = sorted(f for f in flags if f"`{f}" not in section)
        assert not missing, (name, missing)


def _json_keys(schema: dict, node: dict, prefix: str = "", within: tuple = ()) -> set[str]:
    """Every key path of a JSON Schema (pydantic's own rendering of the validator); a table
    that holds tables of its own kind (nested [params]) is followed once."""
    while "$ref" in node:
        if node["$ref"] in within:
            return set()
        within = (*within, node["$ref"])
        node = schema["$defs"][node["$ref"].split("/")[-1]]
    keys = set()
    for alt in node.get("anyOf", []) + node.get("oneOf", []) + node.get("allOf", []):
        keys |= _json_keys(schema, alt, prefix, within)
    if isinstance(node.get("items"), dict):
        keys |= _json_keys(schema, node["items"], prefix + "[]", within)
    if isinstance(node.get("additionalProperties"), dict):
        keys |= _json_keys(schema, node["additionalProperties"], prefix + ".<name>", within)
    for name, sub in node.get("properties", {}).items():
        path = f"{prefix}.{name}" if prefix else name
        keys.add(path)
        keys |= _json_keys(schema, sub, path, within)
    return keys


def test_every_config_key_the_validator_accepts_is_in_the_config_reference(ref):
    from stepzoo.config_schema import kinds
    page = ref.config_page()
    sections = dict(re.findall(r"^## (\w+)\n(.*?)(?=^## |\Z)", page, re.M | re.S))
    assert set(sections) == set(kinds())
    for kind, model in kinds().items():
        keys = _json_keys(model.model_json_schema(), model.model_json_schema())
        assert keys, kind
        missing = sorted(k for k in keys if f"- `{k}`:" not in sections[kind])
        assert not missing, (kind, missing)


def test_the_config_reference_lists_the_keys_of_a_query_file(ref):
    """plan-bench's query files are declared (search/world/query_file.py) and documented
    like the TOML kinds: each key of a query, with what it takes."""
    page = ref.config_page()
    section = re.search(r"^## queries\n(.*?)(?=^## |\Z)", page, re.M | re.S)
    assert section, "no queries section"
    for key, takes in (("map", "a string"), ("cell_size", "m/cell"),
                       ("start", "a list of numbers"), ("goal", "a list of numbers"),
                       ("id", "a string or a whole number")):
        line = next((ln for ln in section[1].splitlines() if ln.startswith(f"- `{key}`:")), "")
        assert takes in line, (key, line)


def _documented(section: str, variables, states) -> re.Pattern:
    """The columns a tables-page section names, with `<variable>` and `<state>` standing for
    the folder's own envelope variables and states."""
    names = re.findall(r"`([^`]+)`", section)
    alternatives = {"<variable>": variables, "<state>": states}
    def pattern(name):
        parts = re.split(r"(<variable>|<state>)", name)
        return "".join("(?:" + "|".join(map(re.escape, alternatives[p])) + ")"
                       if p in alternatives else re.escape(p) for p in parts)
    return re.compile("|".join(pattern(n) for n in names))


def test_every_column_of_a_finished_sweep_is_in_the_tables_reference(ref, tiny_sweep):
    import json
    _, folder = tiny_sweep
    page = ref.tables_page()
    model = json.loads((folder / "manifest.json").read_text())["model_spec"]
    files = sorted(folder.glob("*.parquet")) + sorted(folder.glob("*.csv"))
    assert {f.stem for f in files} >= {"runs", "limits", "summary", "eigenvalues"}
    for f in files:
        table = pd.read_parquet(f) if f.suffix == ".parquet" else pd.read_csv(f)
        section = page.split(f"### `{f.stem}`")[1].split("\n#")[0]
        assert f"`{f.name}`" in section
        documented = _documented(section, model["variables"], model["states"])
        missing = [c for c in table.columns if not documented.fullmatch(c)]
        assert not missing, (f.name, missing)


def test_the_exit_statuses_page_lists_every_status_a_command_returns(ref):
    statuses = ref.exit_statuses()
    assert sorted(statuses) == [0, 1, 2, ref.cli().INTERRUPTED]
    page = ref.exit_page()
    for n, text in statuses.items():
        assert f"| {n} | {' '.join(text.split())} |" in page


def test_getting_started_shows_the_readme_s_api_example_and_its_output():
    """test_wheel.py runs the README's example from the installed wheel and checks that it
    prints what the README says; Getting started repeats it unchanged."""
    code = re.search(r"```python\n(.*?)```", README, re.S).group(1)
    assert len(code.splitlines()) <= 16
    said = re.search(r"prints `(.*?)` and `(.*?)`", README).groups()
    guide = (ROOT / "docs/getting-started.md").read_text()
    assert re.search(r"```python\n(.*?)```", guide, re.S).group(1) == code
    assert re.search(r"prints `(.*?)` and `(.*?)`", guide).groups() == said


def test_the_readme_is_a_short_front_door_that_agrees_with_the_code(ref):
    from stepzoo.integrators import METHODS
    assert len(README.splitlines()) <= 150
    assert f"a zoo of {len(METHODS)} methods" in " ".join(README.split())
    lines = [line for line in README.splitlines() if line.startswith("- `stepzoo ")]
    assert [line.split("`")[1] for line in lines] == [f"stepzoo {c}" for c in ref.cli().COMMANDS]
    text = re.sub(r"\]\([^)]*\)", "]", README)           # link targets may name dated pages
    assert not re.search(r"\b20\d\d-\d\d-\d\d\b", text)
    assert not re.search(r"(?<![\w.])/(work|home|Users|tmp|root)/", text)
    for target in re.findall(r"\]\(([^)#]+)", README):
        assert (ROOT / target).exists(), target


def test_the_site_builds_strictly_and_loads_nothing_from_the_network(site):
    out, done = site
    assert done.returncode == 0, done.stderr[-3000:]
    for page in ("reference/commands", "reference/config", "reference/tables",
                 "reference/exit-statuses", "api", "design", "changelog"):
        assert (out / f"{page}.html").is_file(), page
    api = (out / "api.html").read_text()
    assert "integrate_batch" in api and "reference" in api
    loads = re.compile(r"<(?:script|link|img|iframe)\b[^>]*\b(?:src|href)="
                       r"[\"']((?:https?:)?//[^\"']+)")
    for html in out.rglob("*.html"):
        remote = loads.findall(html.read_text())
        assert not remote, (html.name, remote[:3])
    for asset in list(out.rglob("*.css")) + list(out.rglob("*.js")):
        text = asset.read_text(errors="replace")
        assert "fonts.googleapis" not in text and "fonts.gstatic" not in text, asset.name


@pytest.mark.skipif(report_browser.unavailable() is not None,
                    reason=f"no browser test: {report_browser.unavailable()}")
def test_the_site_opened_from_the_file_system_searches_with_the_network_refused(site):
    out, done = site
    assert done.returncode == 0, done.stderr[-3000:]
    with report_browser.visit(out / "index.html") as seen:
        seen.page.keyboard.press("s")                     # Material's search shortcut
        seen.page.keyboard.type("Robertson")
        seen.page.wait_for_selector(".md-search-result__item", timeout=20_000)
        hits = seen.page.locator(".md-search-result__item").count()
    assert hits >= 1
    assert not seen.errors and not seen.requests, (seen.errors, seen.requests)

"""The site's mkdocs hook. It generates the reference pages from the code when the site is
built: every command and flag from the command line's parsers, every config key of every file
kind from the config schema, every results table's columns, the exit statuses. Each page is a
function returning Markdown, so tests/test_docs.py checks the very text the site shows. It
also lays the sources out for the API pages and places pages the nav does not name."""
from __future__ import annotations

import argparse
import importlib
import json
import re
import shutil
import tomllib
import types
import typing
from pathlib import Path
from typing import Annotated

from mkdocs.plugins import event_priority
from mkdocs.structure.files import File

# The command line's module (on main since the commands moved there): the one line to change
# when it moves again.
CLI = "stepzoo.cli"


def cli():
    return importlib.import_module(CLI)


def pages() -> dict:
    """Site path -> the page's Markdown."""
    return {"reference/commands.md": commands_page(), "reference/config.md": config_page(),
            "reference/tables.md": tables_page(), "reference/exit-statuses.md": exit_page()}


@event_priority(100)
def on_config(config):
    """mkdocs hook, before mkdocstrings' (which looks for its paths when it starts): lay out
    the sources as they are imported, for the API pages; and give every page of docs/ that
    the nav does not name a place in it."""
    source_tree(Path(config.config_file_path).parent)
    unlisted(config)
    return config


def _named(nav) -> set[str]:
    """The pages a nav (mkdocs.yml's list of sections and pages) names."""
    if isinstance(nav, str):
        return {nav}
    if isinstance(nav, list):
        return set().union(*map(_named, nav))
    if isinstance(nav, dict):
        return set().union(*map(_named, nav.values()))
    return set()


def unlisted(config) -> None:
    """Append the pages of docs/ that the nav does not name: a study or a record of
    measurements (its name says so) to Studies, any other to Guides, titled by its first
    heading. Pages come from several hands; none should be left out of the site, nor break
    its build."""
    docs, named = Path(config.docs_dir), _named(config.nav)
    sections = {next(iter(item)): item[next(iter(item))] for item in config.nav
                if isinstance(item, dict) and isinstance(next(iter(item.values())), list)}
    for page in sorted(docs.rglob("*.md")):
        path = page.relative_to(docs).as_posix()
        if path in named or config.exclude_docs.match_file(path):
            continue
        title = next((line[2:].strip() for line in page.read_text().splitlines()
                      if line.startswith("# ")), page.stem)
        study = "study" in page.stem or "measurement" in page.stem
        sections["Studies" if study else "Guides"].append({title: path})


def source_tree(root: Path) -> Path:
    """`root/.docs-src/stepzoo`: the package as an install lays it out (its top-level folders
    mapped under one namespace by pyproject's package-dir), as links. mkdocstrings reads the
    API from the source files there, since the repository's own layout has no `stepzoo`
    folder holding them all."""
    mapping = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"][
        "package-dir"]
    tree = root / ".docs-src"
    shutil.rmtree(tree, ignore_errors=True)
    top = tree / "stepzoo"
    top.mkdir(parents=True)
    for entry in (root / mapping["stepzoo"]).iterdir():
        (top / entry.name).symlink_to(entry.resolve())
    for package, folder in mapping.items():
        if package.count(".") == 1:
            (top / package.split(".")[1]).symlink_to((root / folder).resolve())
    return tree


def on_files(files, config):
    """mkdocs hook: add the generated pages to the site's files."""
    for path, text in pages().items():
        files.append(File.generated(config, path, content=text))
    return files


def _cell(text) -> str:
    """`text` as one line of Markdown prose (a help text may span lines; its brackets, such
    as units, are no links)."""
    return " ".join(str(text).split()).replace("[", "\\[").replace("]", "\\]")


# ------------------------------------------------------------------------------- commands

def subparsers(parser: argparse.ArgumentParser) -> dict:
    """A parser's subcommands, name -> parser."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def command_parsers() -> dict:
    """Every command's parser, complete with its own flags, by name (the registry's order)."""
    module = cli()
    return {name: subparsers(module.build_parser(name))[name] for name in module.COMMANDS}


def _indented(text: str) -> str:
    """`text` as a Markdown code block."""
    return "\n".join("    " + line for line in text.strip().splitlines())


def _help(action, prog: str) -> str:
    text = action.help or ""
    if "%(" in text:
        text = text % {**vars(action), "prog": prog}
    return _cell(text)


def _argument(action, prog: str) -> str:
    if action.option_strings:
        takes = "" if action.nargs == 0 else f" {action.metavar or action.dest.upper()}"
        name = ", ".join(f"`{o}{takes}`" for o in action.option_strings)
    else:
        name = f"`{action.metavar or action.dest}`"
    notes = []
    if action.choices:
        notes.append("one of " + ", ".join(f"`{c}`" for c in action.choices))
    if action.required and action.option_strings:
        notes.append("required")
    if action.nargs == "*" or action.nargs == "+" or isinstance(action, argparse._AppendAction):
        notes.append("repeatable" if action.option_strings else "one or more")
    text = _help(action, prog)
    if (action.option_strings and action.nargs != 0 and action.default not in (None, False)
            and action.default is not argparse.SUPPRESS and "default" not in text):
        notes.append(f"default `{action.default}`")
    tail = f" ({'; '.join(notes)})" if notes else ""
    return f"- {name}{tail}" + (f": {text}" if text else "")


def commands_page() -> str:
    module = cli()
    top = module.build_parser()
    lines = ["# Commands", "",
             "Every command and flag of `stepzoo`, generated from its argument parsers when "
             "the site is built. `stepzoo COMMAND --help` prints the same.", "",
             _indented(top.format_usage()), ""]
    lines += [_argument(a, top.prog) for a in top._actions
              if a.help is not argparse.SUPPRESS and not isinstance(a, argparse._SubParsersAction)]
    lines += ["", "Exit statuses: [the exit statuses](exit-statuses.md).", ""]
    for name, parser in command_parsers().items():
        lines += [f"## `stepzoo {name}`", "", _cell(module.COMMANDS[name][1]), "",
                  _indented(parser.format_usage()), ""]
        lines += [_argument(a, parser.prog) for a in parser._actions
                  if a.help is not argparse.SUPPRESS]
        lines.append("")
    return "\n".join(lines)


# ---------------------------------------------------------------------------------- config

def _unwrap(annotation):
    """The types a field's value may hold, under Annotated and unions."""
    if typing.get_origin(annotation) is Annotated:
        return _unwrap(typing.get_args(annotation)[0])
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        return [t for a in typing.get_args(annotation) for t in _unwrap(a)]
    return [annotation]


def _tables(annotation) -> list[tuple[str, type]]:
    """The tables a field's value may hold: (how a key path continues into it, its model);
    a list of tables continues with `[]`, a table of named tables with `.<name>`."""
    from stepzoo.config_schema import Schema
    found = []
    for t in _unwrap(annotation):
        origin, args = typing.get_origin(t), typing.get_args(t)
        if isinstance(t, type) and issubclass(t, Schema):
            found.append(("", t))
        elif origin in (tuple, list) and args:
            found += [("[]" + s, m) for s, m in _tables(args[0])]
        elif origin is dict and len(args) == 2:
            found += [(".<name>" + s, m) for s, m in _tables(args[1])]
    return found


def _named_values(model):
    """The type of the keys a table takes by any name (pydantic's typed extras), or None."""
    if model.model_config.get("extra") != "allow":
        return None
    return typing.get_type_hints(model, include_extras=True).get("__pydantic_extra__")


def config_keys(model, prefix: str = "", within: tuple = ()):
    """Every key a file of `model` may hold: (dotted path, its FieldInfo, its doc); a table
    that holds tables of its own kind (nested [params]) is listed once, not unrolled."""
    from pydantic.fields import FieldInfo
    within = (*within, model)
    named = _named_values(model)
    if named is not None:
        value = typing.get_args(named)[1]
        path = prefix + "<name>"
        yield path, FieldInfo.from_annotation(value), "any key you name, as the table says"
        for step, inner in _tables(value):
            if inner not in within:
                yield from config_keys(inner, f"{path}{step}.", within)
    for name, info in model.model_fields.items():
        path = prefix + (info.alias or name)
        tables = _tables(info.annotation)
        doc = info.description or ((tables[0][1].__doc__ or "") if tables else "")
        yield path, info, doc
        for step, inner in tables:
            if inner not in within:
                yield from config_keys(inner, f"{path}{step}.", within)


def _default(info) -> str:
    from pydantic_core import PydanticUndefined
    if info.default_factory is not None:
        value = info.default_factory()
    elif info.default is PydanticUndefined:
        return "required"
    else:
        value = info.default
    if hasattr(value, "model_dump"):
        return "its keys' defaults"
    if value is None:
        return "none"
    try:
        return f"`{json.dumps(value)}`"
    except TypeError:
        return f"`{value!r}`"


def config_page() -> str:
    from stepzoo import config_schema
    lines = ["# Configuration files", "",
             "Every key of every file kind, generated from the config schema "
             "(`stepzoo.config_schema`) when the site is built: what it takes (range, unit and "
             "why), its default and what it means. A key the schema does not declare is "
             "refused, and every mistake of a file is reported at once. `a.b` is key `b` of "
             "table `[a]`; `a[].b` is key `b` of each `[[a]]` table; `a.<name>.b` is key `b` "
             "of a table you name under `[a]`.", ""]
    for kind, model in config_schema.kinds().items():
        doc = _cell(model.__doc__ or "")
        lines += [f"## {kind}", "", doc, ""] if doc else [f"## {kind}", ""]
        for path, info, doc in config_keys(model):
            what = _cell(config_schema.describe(info))
            about = _cell(doc).rstrip(".")
            default = _default(info)
            default = ("" if path.endswith("<name>") else "; required" if default == "required"
                       else f"; default {default}")
            lines.append(f"- `{path}`: {about}{'. ' if about else ''}Takes {what}{default}.")
        lines.append("")
    return "\n".join(lines)


# ---------------------------------------------------------------------------------- tables

def sweep_tables() -> dict:
    """A sweep folder's tables -> their columns; `<variable>` stands for each envelope
    variable, `<state>` for each state of the model."""
    from stepzoo.bench.sweep import tables as schema
    return {
        "runs": schema.run_columns([schema.VARIABLE], [schema.STATE], vehicle=True),
        "limits": schema.limit_columns([schema.VARIABLE], [schema.STATE]),
        "summary": list(schema.SUMMARY),
        "eigenvalues": schema.eigen_columns([schema.VARIABLE]),
        # Assembled by the sweep rather than declared: what a reader needs, then the states and
        # which sample it is (test_docs checks this against a finished sweep's file).
        "trajectories": [*schema.REQUIRED["trajectories"], schema.STATE, "past_limit"],
    }


def plan_tables() -> dict:
    """A plan's and a plan-bench folder's tables -> {column: its doc line}."""
    from stepzoo.search.plans import schema as ps
    return {"plan.json": ps.PLAN_KEYS, "plan.json stats": ps.STATS_KEYS,
            "plan.json replay": ps.REPLAY_COLUMNS, "plan-bench runs": ps.RUN_COLUMNS,
            "plan-bench summary": ps.SUMMARY_COLUMNS, "plan-bench summary, several integrators":
            ps.INTEGRATOR_COLUMNS}


def tables_page() -> str:
    from stepzoo.bench.sweep import tables as schema
    lines = ["# Results tables", "",
             "The columns of every table a command writes, generated from the table "
             "declarations when the site is built. A column named here is a contract: it keeps "
             "its name and meaning. `<variable>` stands for each envelope variable of the "
             "config and `<state>` for each state of the model; `err_pos` and `err_final` "
             "exist for models with a position (X, Y) only. **bold**: a column every reader "
             "of a folder relies on; *italic*: a measured time, which differs between two "
             "runs of the same config.", "",
             "## Sweep folders (`stepzoo sweep`)", ""]
    for table, columns in sweep_tables().items():
        files = [f"{table}.{ext}" for ext, names in (("parquet", schema.PARQUET),
                                                     ("csv", schema.CSV)) if table in names]
        required = schema.REQUIRED.get(table, [])
        shown = [f"**`{c}`**" if c in required else f"*`{c}`*" if c in schema.MEASURED
                 else f"`{c}`" for c in columns]
        lines += [f"### `{table}`", "", "Files: " + ", ".join(f"`{f}`" for f in files) + ".",
                  "", "| column | meaning |", "| --- | --- |"]
        lines += [f"| {name} | {schema.COLUMN_DOC[c]} |" for c, name in zip(columns, shown)]
        lines.append("")
    lines += ["## Plans and plan-bench folders (`stepzoo plan`, `stepzoo plan-bench`)", "",
              "`stepzoo plan` writes `plan.json`; `stepzoo plan-bench` writes `runs` (one row "
              "per query, integrator and run) and `summary` (one row, or one per integrator "
              "when there are several) as Parquet and CSV. Units are in brackets.", ""]
    for table, columns in plan_tables().items():
        lines += [f"### `{table}`", "", "| column | meaning |", "| --- | --- |"]
        lines += [f"| `{c}` | {_cell(doc).replace('|', '&#124;')} |" for c, doc in columns.items()]
        lines.append("")
    return "\n".join(lines)


# ---------------------------------------------------------------------------- exit statuses

def exit_statuses() -> dict[int, str]:
    """The command line's exit statuses -> their meaning, from its `--help` epilogue."""
    found, current = {}, None
    for line in cli().EXIT_STATUSES.splitlines()[1:]:
        number = re.match(r"\s*(\d+)\s+(.*)", line)
        if number:
            current = int(number.group(1))
            found[current] = number.group(2)
        elif current is not None:
            found[current] += " " + line.strip()
    return found


def exit_page() -> str:
    lines = ["# Exit statuses", "",
             "What every `stepzoo` command's exit status means, as its `--help` lists it "
             "(generated when the site is built). A script may rely on these.", "",
             "| status | meaning |", "| --- | --- |"]
    lines += [f"| {n} | {_cell(text)} |" for n, text in exit_statuses().items()]
    return "\n".join(lines) + "\n"

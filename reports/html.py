"""Writing the report: a self-contained index.html (inline style, PNGs beside it, nothing
fetched from a network) and summary.md with the same facts, tables and figures."""
from __future__ import annotations

import html
from pathlib import Path

from stepzoo.output import atomic_write
from stepzoo.reports.tables import to_html, to_markdown

STYLE = """
body { font-family: sans-serif; max-width: 1300px; margin: 1.5em auto; padding: 0 1em;
       color: #222; line-height: 1.4; }
table { border-collapse: collapse; font-size: 0.85em; margin: 0.5em 0 1.5em; }
th, td { border: 1px solid #bbb; padding: 0.2em 0.5em; text-align: left; }
th { background: #eef2f7; }
figure { margin: 0 0 2em; }
figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption, .caption { font-size: 0.9em; color: #444; max-width: 60em; }
dl { display: grid; grid-template-columns: max-content auto; gap: 0.2em 1em; }
dt { font-weight: bold; }
"""


def _esc(text) -> str:
    return html.escape(str(text))


def _figure_html(shown) -> str:
    parts = [f'<section id="fig{shown.number}">',
             f"<h2>Figure {shown.number}. {_esc(shown.title)}</h2>",
             f'<p class="caption">{_esc(shown.caption)}</p>']
    for i, (name, sub) in enumerate(shown.images):
        parts.append(f'<figure id="fig{shown.number}-{i + 1}"><img src="{_esc(name)}" '
                     f'alt="Figure {shown.number}: {_esc(shown.title)}">'
                     + (f"<figcaption>{_esc(sub)}</figcaption>" if sub else "") + "</figure>")
    parts.append("</section>")
    return "\n".join(parts)


def index_html(title: str, facts: list, tables: list, figures: list) -> str:
    """The page: facts (label, value) about the inputs, then the tables, then the figures."""
    facts_html = "\n".join(f"<dt>{_esc(k)}</dt><dd>{_esc(v)}</dd>" for k, v in facts)
    tables_html = "\n".join(
        f"<section><h2>{_esc(t.title)}</h2>\n<p class=\"caption\">{_esc(t.caption)}</p>\n"
        + (to_html(t.rows, t.columns) if t.rows else "<p>(nothing to show)</p>")
        + "\n</section>" for t in tables)
    toc = "\n".join(f'<li><a href="#fig{f.number}">Figure {f.number}. {_esc(f.title)}</a></li>'
                    for f in figures)
    figures_html = "\n".join(_figure_html(f) for f in figures)
    return (f'<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
            f"<title>{_esc(title)}</title>\n<style>{STYLE}</style>\n</head>\n<body>\n"
            f"<h1>{_esc(title)}</h1>\n<dl>\n{facts_html}\n</dl>\n<ul>\n{toc}\n</ul>\n"
            f"{tables_html}\n{figures_html}\n</body>\n</html>\n")


def summary_md(title: str, facts: list, tables: list, figures: list) -> str:
    lines = [f"# {title}", ""]
    lines += [f"- **{k}**: {v}" for k, v in facts]
    for t in tables:
        lines += ["", f"## {t.title}", "", t.caption, "",
                  to_markdown(t.rows, t.columns) if t.rows else "(nothing to show)"]
    for f in figures:
        lines += ["", f"## Figure {f.number}. {f.title}", "", f.caption]
        for name, sub in f.images:
            lines += ["", f"![Figure {f.number}]({name})"] + (["", f"*{sub}*"] if sub else [])
    return "\n".join(lines) + "\n"


def write_report(out_dir, title: str, facts: list, tables: list, figures: list):
    """Write index.html and summary.md into out_dir; returns their paths."""
    out_dir = Path(out_dir)
    index = atomic_write(out_dir / "index.html", index_html(title, facts, tables, figures))
    summary = atomic_write(out_dir / "summary.md", summary_md(title, facts, tables, figures))
    return index, summary

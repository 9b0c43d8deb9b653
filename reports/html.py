"""Writing the report: a self-contained index.html (inline style, plotly.js inlined once for
the interactive figures, static PNGs beside it, nothing fetched from a network; readable on
a phone) and summary.md with the same facts, tables and figures. The library and each plot
come packed (interactive.pack); the page's one script unpacks them and draws the plots."""
from __future__ import annotations

import html
from collections.abc import Sequence
from pathlib import Path

from stepzoo.output import write_file
from stepzoo.reports.tables import to_html, to_markdown

STYLE = """
body { font-family: sans-serif; max-width: 1300px; margin: 1.5em auto; padding: 0 1em;
       color: #222; line-height: 1.4; }
h1 { font-size: 1.6em; } h2 { font-size: 1.25em; }
.scroll { overflow-x: auto; max-width: 100%; margin: 0.5em 0 1.5em; }
table { border-collapse: collapse; font-size: 0.85em; }
th, td { border: 1px solid #bbb; padding: 0.2em 0.5em; text-align: left; }
th { background: #eef2f7; }
figure { margin: 0 0 2em; }
figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption, .caption { font-size: 0.9em; color: #444; max-width: 60em; }
.plot { width: 100%; margin: 0.5em 0; }
details { margin: 0.3em 0 1em; } summary { cursor: pointer; color: #1f4e79; }
dl { display: grid; grid-template-columns: max-content minmax(0, 1fr); gap: 0.2em 1em; }
dt { font-weight: bold; } dd { margin: 0; overflow-wrap: anywhere; }
@media (max-width: 600px) { body { padding: 0 0.5em; }
  dl { grid-template-columns: minmax(0, 1fr); } dd { margin-bottom: 0.4em; } }
"""


# Unpacks plotly.js (gzip, base64) with the browser's own gzip, runs it, then draws every
# plot from its packed figure. Where the browser cannot unpack, the static copies open.
DRAW_JS = """
(async () => {
  const unpack = async (el) => {
    const bytes = Uint8Array.from(atob(el.textContent), c => c.charCodeAt(0));
    const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream("gzip"));
    return await new Response(stream).text();
  };
  try {
    const lib = document.createElement("script");
    lib.textContent = await unpack(document.getElementById("plotly-js"));
    document.head.appendChild(lib);
    for (const spec of document.querySelectorAll("script.plot-spec")) {
      await Plotly.newPlot(spec.dataset.for, JSON.parse(await unpack(spec)));
    }
  } catch (err) {
    document.querySelectorAll("details").forEach(d => { d.open = true; });
    document.getElementById("no-plots").hidden = false;
    throw err;
  }
})();
"""


def _esc(text) -> str:
    return html.escape(str(text))


def _figure_html(shown, plots: list) -> str:
    """A figure's section: the interactive plot(s) when given, each static PNG under a
    disclosure (the plot's copy for papers), else the PNGs themselves."""
    parts = [f'<section id="fig{shown.number}">',
             f"<h2>Figure {shown.number}. {_esc(shown.title)}</h2>",
             f'<p class="caption">{_esc(shown.caption)}</p>']
    if len(plots) > len(shown.images):
        raise ValueError(f"figure {shown.number}: more plots than static images")
    for i, (name, sub) in enumerate(shown.images):
        img = (f'<img src="{_esc(name)}" loading="lazy" '
               f'alt="Figure {shown.number}: {_esc(shown.title)}">')
        caption = f"<figcaption>{_esc(sub)}</figcaption>" if sub else ""
        if i < len(plots):
            body = (f'<div class="plot">{plots[i]}</div>{caption}<details><summary>static '
                    f"copy ({_esc(name)})</summary>{img}</details>")
        else:
            body = img + caption
        parts.append(f'<figure id="fig{shown.number}-{i + 1}">{body}</figure>')
    parts.append("</section>")
    return "\n".join(parts)


def _table_html(t) -> str:
    return (f"<section><h2>{_esc(t.title)}</h2>\n<p class=\"caption\">{_esc(t.caption)}</p>\n"
            + (f'<div class="scroll">{to_html(t.rows, t.columns)}</div>' if t.rows
               else "<p>(nothing to show)</p>") + "\n</section>")


def index_html(title: str, facts: list, tables: list, figures: list,
               interactive: dict | None = None, plotly_js: str = "",
               appendix: Sequence = ()) -> str:
    """The page: facts (label, value) about the inputs, the tables, the figures, then the
    appendix tables. `interactive` maps a figure's number to its plots' HTML fragments, which
    need `plotly_js` (the library, packed, inlined once in the head)."""
    interactive = interactive or {}
    facts_html = "\n".join(f"<dt>{_esc(k)}</dt><dd>{_esc(v)}</dd>" for k, v in facts)
    tables_html = "\n".join(_table_html(t) for t in tables)
    toc = "\n".join(f'<li><a href="#fig{f.number}">Figure {f.number}. {_esc(f.title)}</a></li>'
                    for f in figures)
    toc += "".join(f'\n<li><a href="#appendix">Appendix. {_esc(t.title)}</a></li>'
                   for t in appendix[:1])
    figures_html = "\n".join(_figure_html(f, interactive.get(f.number, [])) for f in figures)
    appendix_html = ('<div id="appendix">\n' + "\n".join(_table_html(t) for t in appendix)
                     + "\n</div>") if appendix else ""
    if interactive and not plotly_js:
        raise ValueError("interactive figures need plotly_js")
    script = (f'<script id="plotly-js" type="application/octet-stream">{plotly_js}</script>\n'
              if interactive else "")
    how = ("<p class=\"caption\">The figures are interactive: drag to zoom (double-click "
           "resets), hover for exact values, click a legend entry to hide or show it, "
           "double-click one to show it alone. A static copy of each is beside this page.</p>\n"
           '<p class="caption" id="no-plots" hidden>This browser cannot unpack the '
           "interactive figures; their static copies are shown.</p>\n"
           if interactive else "")
    draw = f"<script>{DRAW_JS}</script>\n" if interactive else ""
    return (f'<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
            f'<meta name="viewport" content="width=device-width, initial-scale=1">\n'
            f"<title>{_esc(title)}</title>\n<style>{STYLE}</style>\n{script}</head>\n<body>\n"
            f"<h1>{_esc(title)}</h1>\n<dl>\n{facts_html}\n</dl>\n{how}<ul>\n{toc}\n</ul>\n"
            f"{tables_html}\n{figures_html}\n{appendix_html}\n{draw}</body>\n</html>\n")


def _table_md(t) -> list:
    return ["", f"## {t.title}", "", t.caption, "",
            to_markdown(t.rows, t.columns) if t.rows else "(nothing to show)"]


def summary_md(title: str, facts: list, tables: list, figures: list,
               appendix: Sequence = ()) -> str:
    lines = [f"# {title}", ""]
    lines += [f"- **{k}**: {v}" for k, v in facts]
    for t in tables:
        lines += _table_md(t)
    for f in figures:
        lines += ["", f"## Figure {f.number}. {f.title}", "", f.caption]
        for name, sub in f.images:
            lines += ["", f"![Figure {f.number}]({name})"] + (["", f"*{sub}*"] if sub else [])
    for t in appendix:
        lines += _table_md(t)
    return "\n".join(lines) + "\n"


def write_report(out_dir, title: str, facts: list, tables: list, figures: list,
                 interactive: dict | None = None, plotly_js: str = "", appendix: Sequence = ()):
    """Write index.html and summary.md into out_dir, a new folder that is renamed into
    place whole once written (results_folder.replacing); returns their paths."""
    out_dir = Path(out_dir)
    index = write_file(out_dir / "index.html", index_html(
        title, facts, tables, figures, interactive, plotly_js, appendix).encode())
    summary = write_file(out_dir / "summary.md",
                         summary_md(title, facts, tables, figures, appendix).encode())
    return index, summary

"""A one-page HTML index of a run's pictures and figures (``index.html``), viewable offline."""

from __future__ import annotations

import html
from pathlib import Path

from orthomvp.io.outputs import atomic_path

STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em auto; padding: 0 1em; max-width: 1100px;
       color: #222; }
figure { margin: 1.5em 0; } img { max-width: 100%; height: auto; border: 1px solid #ccc; }
figcaption { font-size: 0.95em; color: #444; margin-top: 0.4em; }
pre { background: #f4f4f4; padding: 1em; white-space: pre-wrap; overflow-wrap: anywhere; }
table.about { border-collapse: collapse; font-size: 0.95em; }
table.about th { text-align: left; padding: 0.15em 1em 0.15em 0; vertical-align: top;
                 font-weight: 600; white-space: nowrap; }
table.about td { padding: 0.15em 0; }
""".strip()
"""The summary wraps inside the page (pre-wrap) rather than running off its side, and pictures
shrink to the page's width."""


def write_index(
    path: str | Path,
    title: str,
    summary: list[str],
    figures: list[tuple[str, str]],
    files: list[tuple[str, str]],
    about: list[tuple[str, str]] = (),
) -> None:
    """Write ``index.html``: a table ``about`` the run (label, value: version, date,
    parameters), the ``summary`` lines, each picture of ``figures`` (file name relative to the
    page, caption) and a list of the other ``files`` (name, description)."""
    esc = html.escape
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f"<title>{esc(title)}</title><style>{STYLE}</style></head><body>",
        f"<h1>{esc(title)}</h1>",
    ]
    if about:
        parts.append('<table class="about">')
        parts += [f"<tr><th>{esc(k)}</th><td>{esc(v)}</td></tr>" for k, v in about]
        parts.append("</table>")
    parts.append("<pre>" + esc("\n".join(summary)) + "</pre>")
    for name, caption in figures:
        parts.append(
            f'<figure><a href="{esc(name)}"><img src="{esc(name)}" alt="{esc(caption)}"></a>'
            f"<figcaption>{esc(caption)}</figcaption></figure>"
        )
    parts.append("<h2>Files</h2><ul>")
    parts += [f'<li><a href="{esc(n)}">{esc(n)}</a>: {esc(d)}</li>' for n, d in files]
    parts.append("</ul></body></html>")
    with atomic_path(path) as tmp:
        tmp.write_text("\n".join(parts) + "\n", encoding="utf-8")

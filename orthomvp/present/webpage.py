"""A one-page HTML index of a run's pictures and figures (``index.html``), viewable offline."""

from __future__ import annotations

import html
from pathlib import Path

from orthomvp.raster import atomic_path

STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1100px; color: #222; }
figure { margin: 1.5em 0; } img { max-width: 100%; border: 1px solid #ccc; }
figcaption { font-size: 0.95em; color: #444; margin-top: 0.4em; }
pre { background: #f4f4f4; padding: 1em; overflow-x: auto; }
""".strip()


def write_index(
    path: str | Path,
    title: str,
    summary: list[str],
    figures: list[tuple[str, str]],
    files: list[tuple[str, str]],
) -> None:
    """Write ``index.html``: the ``summary`` lines, each picture of ``figures`` (file name
    relative to the page, caption) and a list of the other ``files`` (name, description)."""
    esc = html.escape
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{esc(title)}</title><style>{STYLE}</style></head><body>",
        f"<h1>{esc(title)}</h1>",
        "<pre>" + esc("\n".join(summary)) + "</pre>",
    ]
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

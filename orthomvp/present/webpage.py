"""A run's report as HTML (the summary, its pictures with captions, its files), for the static
page of ``orthomvp view --export`` that the demo writes as its ``index.html``."""

from __future__ import annotations

import html


def report_html(
    summary: list[str],
    figures: list[tuple[str, str]],
    files: list[tuple[str, str]],
    about: list[tuple[str, str]] = (),
) -> str:
    """The body of a run's report: a table ``about`` the run (label, value: version, date,
    parameters), the ``summary`` lines, each picture of ``figures`` (file name relative to the
    page, caption) and a list of the other ``files`` (name, description)."""
    esc = html.escape
    parts = []
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
    parts.append("</ul>")
    return "\n".join(parts)

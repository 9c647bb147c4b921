"""The text panel of an exported ``geoloc view`` page.

viser's scene serializer records the 3D scene only, not the GUI, so an exported
``.html`` would not say which record it shows or how far it is from the truth.
:func:`with_summary` writes that text (the viewer's summary panel) into the page as
a fixed panel over the scene, and names the page after the scene.
"""

from __future__ import annotations

import html
import re

#: id of the injected panel (the tests look for it).
PANEL_ID = "geoloc-summary"

_STYLE = (
    "position:fixed;right:12px;top:12px;z-index:10000;max-width:34em;max-height:96vh;overflow:auto;"
    "background:rgba(24,24,28,0.88);color:#e8e8e8;font:13px/1.45 system-ui,sans-serif;"
    "padding:8px 12px;border-radius:6px;border:1px solid #555"
)


def markdown_to_html(text: str) -> str:
    """The small markdown of the viewer's panels (``**bold**``, lines, blank lines) as HTML."""
    lines: list[str] = []
    for line in text.splitlines():
        s = re.sub(r"\*\*(.+?)\*\*", r"<b>\1</b>", html.escape(line.strip()))
        if s or (lines and lines[-1]):  # one blank line at most between paragraphs
            lines.append(s)
    while lines and not lines[-1]:
        lines.pop()
    return "<br>".join(lines)


def with_summary(page: str, title: str, summary_markdown: str, note: str = "", extra_html: str = "") -> str:
    """``page`` (viser's ``as_html``) with a ``<title>`` and the summary as a fixed panel
    (``extra_html`` appended to it: the layers' own exports, e.g. the frame's picture)."""
    t = html.escape(title)
    if "<title>" in page:
        page = re.sub(r"<title>.*?</title>", f"<title>{t}</title>", page, count=1, flags=re.S)
    else:
        page = page.replace("</head>", f"<title>{t}</title></head>", 1)
    body = markdown_to_html(summary_markdown)
    if note:
        body += f'<br><span style="opacity:0.7">{html.escape(note)}</span>'
    body += extra_html
    panel = f'<div id="{PANEL_ID}" style="{_STYLE}">{body}</div>'
    if "</body>" in page:
        return page.replace("</body>", panel + "\n</body>", 1)
    return page + panel

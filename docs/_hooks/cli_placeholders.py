"""MkDocs hook: keep placeholders such as ``units/<scene>__<config>/`` visible in the CLI reference.

mkdocs-click renders each command's help text as Markdown, where ``<scene>`` reads as an (unknown)
HTML tag and disappears from the page. On the CLI reference page only, every tag that is not an
HTML element is written back as text.
"""

from __future__ import annotations

import re

CLI_PAGE = "reference/cli.md"
HTML_ELEMENTS = frozenset(
    "a abbr article aside b blockquote body br button caption code col colgroup dd del details div dl dt em "
    "figcaption figure footer form h1 h2 h3 h4 h5 h6 head header hr html i img input ins kbd label li link "
    "main mark meta nav ol option p path pre script section select small span strong style sub summary sup "
    "svg table tbody td textarea tfoot th thead title tr u ul".split()
)
_TAG = re.compile(r"<(/?)([A-Za-z][\w-]*)>")


def _escape(match: re.Match[str]) -> str:
    if match.group(2).lower() in HTML_ELEMENTS:
        return match.group(0)
    return f"&lt;{match.group(1)}{match.group(2)}&gt;"


def on_page_content(html: str, page, **_: object) -> str:
    if page.file.src_uri != CLI_PAGE:
        return html
    return _TAG.sub(_escape, html)

"""The five pages of the operator app: one HTML shell each, filled in by its script in ``ui/static``.

Every page has the same header: the page links, the state of the current background job, who controls
the cell, and the STOP button (always visible, on every page, for every browser).
"""

from __future__ import annotations

import html

__all__ = ["PAGES", "render_page"]

#: URL path -> (page id, title in the header).
PAGES = {
    "/": ("cell", "Cell"),
    "/live": ("live", "Live"),
    "/capture": ("capture", "Plan & capture"),
    "/inspect": ("inspect", "Calibrate & inspect"),
    "/export": ("export", "Export"),
}


def render_page(path: str, token: str, title: str, version: str) -> str:
    """The HTML of the page at ``path`` (a key of :data:`PAGES`); ``token`` goes into a meta tag for the
    page's scripts (the page is only served to requests that carried the token)."""
    page, heading = PAGES[path]
    links = "".join(
        f'<a href="{p}" class="{"current" if p == path else ""}" data-page="{pid}">{html.escape(t)}</a>'
        for p, (pid, t) in PAGES.items()
    )
    return f"""<!doctype html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<meta name="jcalib-token" content="{html.escape(token)}">
<title>{html.escape(heading)} · jcalib · {html.escape(title)}</title>
<link rel="icon" href="/static/favicon.svg" type="image/svg+xml">
<link rel="stylesheet" href="/static/app.css">
</head>
<body data-page="{page}">
<header>
  <span class="brand">jcalib</span>
  <nav>{links}</nav>
  <span id="job" class="job"></span>
  <span id="control" class="control"></span>
  <button id="stop" class="stop" title="Stop the robot now (any browser)">STOP</button>
</header>
<div id="banner" class="banner" hidden></div>
<main id="main"><h1>{html.escape(heading)}</h1><div id="content"></div></main>
<footer>{html.escape(title)} · jcalib {html.escape(version)}</footer>
<script type="module" src="/static/{page}.js"></script>
</body>
</html>
"""

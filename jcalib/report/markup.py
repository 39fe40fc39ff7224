"""HTML building blocks of the report: escaping, tables, figures, number formats and the page's CSS.

The page is self-contained: inline CSS, PNG figures as base64 ``data:`` URIs, no script, no external
resource. It fits a laptop screen (max width 1100 px; tables wrap instead of scrolling sideways).
"""

from __future__ import annotations

import base64
import html
from typing import Any

__all__ = ["CSS", "esc", "figure", "fmt", "note", "table", "vec"]

CSS = """
*{box-sizing:border-box}
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,"DejaVu Sans",Arial,sans-serif;
 margin:0;background:#f4f5f7;color:#1d232a;line-height:1.45}
main{max-width:1100px;margin:0 auto;padding:16px 24px 40px;background:#fff;min-height:100vh}
h1{font-size:1.5em;margin:0.3em 0}
h2{font-size:1.2em;border-bottom:2px solid #d5dae0;padding-bottom:3px;margin-top:1.6em}
h3{font-size:1.02em;margin:1.1em 0 0.4em}
table{border-collapse:collapse;margin:0.4em 0 1em;max-width:100%;font-size:0.92em}
th,td{border:1px solid #d5dae0;padding:3px 8px;text-align:left;vertical-align:top;
 overflow-wrap:anywhere;word-break:break-word}
th{background:#eef1f4}
td.num{text-align:right;font-variant-numeric:tabular-nums;white-space:nowrap}
.warn{background:#fff4e5;border:2px solid #e67e22;border-radius:6px;padding:8px 14px;margin:12px 0}
.warn h2{border:none;margin:0.2em 0;color:#a04000}
.warn li{margin:0.3em 0}
.warn .hint{margin:0.4em 0 0.2em}
.ok{background:#eafaf1;border:1px solid #58d68d;border-radius:6px;padding:6px 14px;margin:12px 0}
.note{color:#4a5560;font-size:0.9em}
figure{margin:0.6em 0 1.2em}
figure img{max-width:100%;height:auto;display:block}
figcaption{color:#4a5560;font-size:0.88em;margin-top:4px}
table.kv td:first-child{white-space:nowrap;font-weight:600}
code{font-size:0.92em;background:#f0f2f4;padding:0 3px;border-radius:3px;overflow-wrap:anywhere}
"""


def esc(x: Any) -> str:
    """``x`` as escaped HTML text."""
    return html.escape(str(x), quote=True)


def figure(png: bytes, alt: str, caption: str) -> str:
    """A figure with an inline PNG; ``caption`` is HTML."""
    data = base64.b64encode(png).decode("ascii")
    return f'<figure><img alt="{esc(alt)}" src="data:image/png;base64,{data}"><figcaption>{caption}</figcaption></figure>'


def table(header: list[str], rows: list[list[str]], num_cols=frozenset(), cls: str = "") -> str:
    """An HTML table; ``rows`` hold already-escaped cell HTML; ``num_cols`` are right-aligned numbers."""
    head = "".join(f"<th>{esc(h)}</th>" for h in header)
    body = "".join(
        "<tr>" + "".join(f'<td class="num">{c}</td>' if i in num_cols else f"<td>{c}</td>" for i, c in enumerate(r))
        + "</tr>" for r in rows)
    attr = f' class="{cls}"' if cls else ""
    return f"<table{attr}><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def fmt(x: float, digits: int = 6) -> str:
    """A number with ``digits`` significant digits, escaped."""
    return esc(f"{x:.{digits}g}")


def vec(v, spec: str) -> str:
    """Numbers separated by spaces, each formatted by ``spec``."""
    return esc(" ".join(format(float(x), spec) for x in v))


def note(text: str) -> str:
    """A paragraph of explanatory text (``text`` is HTML)."""
    return f'<p class="note">{text}</p>'

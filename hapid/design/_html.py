"""The self-contained HTML page of a design report: inline CSS, figures as base64 PNG
``data:`` URIs, no scripts, no external links."""

from __future__ import annotations

import base64
import html

CSS = """body{font-family:system-ui,sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;
color:#222}h1{font-size:1.5em}h2{font-size:1.2em;border-bottom:1px solid #ccc;margin-top:2em}
table{border-collapse:collapse;margin:.5em 0;font-size:.9em}td,th{border:1px solid #ccc;
padding:.25em .6em;text-align:left;vertical-align:top}th{background:#f3f3f3}
.passed{background:#d8f0d8}.failed{background:#f6d4d4}.not-established{background:#fbeec8}
img{max-width:100%;border:1px solid #eee}figure{margin:1em 0}figcaption{font-size:.85em;
color:#555}pre{background:#f7f7f7;padding:.6em;overflow-x:auto;font-size:.85em}"""


def esc(x) -> str:
    return html.escape(str(x))


def fmt(v) -> str:
    """A cell: 4 significant figures for floats, ``—`` for None."""
    if v is None:
        return "—"
    if isinstance(v, bool):
        return str(v)
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, list | tuple):
        return ", ".join(fmt(x) for x in v)
    return str(v)


def table(header, rows, row_class=None) -> str:
    """An HTML table; ``row_class(row)`` gives each row's CSS class (or None)."""
    head = "".join(f"<th>{esc(h)}</th>" for h in header)
    body = []
    for r in rows:
        cls = row_class(r) if row_class else None
        attr = f' class="{esc(cls)}"' if cls else ""
        body.append(f"<tr{attr}>" + "".join(f"<td>{esc(fmt(c))}</td>" for c in r) + "</tr>")
    return f"<table><tr>{head}</tr>{''.join(body)}</table>"


def figure(fig) -> str:
    """A report figure (``hapid.design._figures.Figure``) as an embedded PNG."""
    data = base64.b64encode(fig.png).decode("ascii")
    return (f'<figure id="fig-{esc(fig.name)}"><img alt="{esc(fig.title)}" '
            f'src="data:image/png;base64,{data}"><figcaption><b>{esc(fig.title)}.</b> '
            f"{esc(fig.caption)} (also {esc(fig.name)}.png, {esc(fig.name)}.pdf)</figcaption></figure>")  # fmt: skip


def page(title: str, sections: list[tuple[str, str]]) -> str:
    """The whole page: ``sections`` are ``(heading, inner HTML)``."""
    body = "".join(f"<h2>{esc(h)}</h2>{inner}" for h, inner in sections)
    return (f'<!DOCTYPE html><html lang="en"><head><meta charset="utf-8"><title>{esc(title)}'
            f"</title><style>{CSS}</style></head><body><h1>{esc(title)}</h1>{body}</body></html>")  # fmt: skip


def verdict_table(checks: list[dict]) -> str:
    """The verdict table (``Check.summary()`` dicts), each row coloured by its verdict."""
    rows = [(c["name"], c["verdict"], c["reason"] or "", c["remedy"] or "") for c in checks]
    return table(("check", "verdict", "reason", "what would establish it"), rows,
                 lambda r: r[1].replace(" ", "-"))  # fmt: skip


def pre(text: str) -> str:
    return f"<pre>{esc(text)}</pre>"


def para(text: str) -> str:
    return f"<p>{esc(text)}</p>"

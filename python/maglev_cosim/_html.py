"""A Markdown report as one self-contained HTML page (the diagnosis's and the real-rig calibration's)."""

from __future__ import annotations

import base64
import re
from pathlib import Path


def write_html(markdown_path: Path, html_path: Path) -> Path:
    """A self-contained HTML page from a Markdown report: tables rendered, every PNG it links
    embedded as a data URI, so that the one file can be mailed or archived."""
    # markdown: imported here, where it is used (the one function of the package that needs it)
    import markdown

    folder = markdown_path.parent
    body = markdown.markdown(markdown_path.read_text(), extensions=["tables"])

    def embed(m: re.Match) -> str:
        png = folder / m.group(1)
        if not png.is_file():
            return m.group(0)
        return f'src="data:image/png;base64,{base64.b64encode(png.read_bytes()).decode()}"'

    body = re.sub(r'src="([^"]+\.png)"', embed, body)
    title = markdown_path.read_text().splitlines()[0].lstrip("# ").strip() if markdown_path.stat().st_size else "report"
    style = ("body{font-family:sans-serif;max-width:70em;margin:2em auto;padding:0 1em;line-height:1.45}"
             "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;padding:.25em .6em;"
             "text-align:left}th{background:#eee}img{max-width:100%}code{background:#f4f4f4;padding:0 .2em}")
    html_path.write_text(f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><title>{title}</title>'
                         f"<style>{style}</style></head><body>\n{body}\n</body></html>\n")
    return html_path

"""Small HTML pieces the report pages share: a table, and an image as a base64 PNG data URL (no external request)."""

from __future__ import annotations

import base64
import html
import io
from collections.abc import Sequence
from typing import Any

from PIL import Image
from torch import Tensor

from camdegrade._support.pixels import unit_to_bytes


def table(rows: Sequence[Sequence[Any]], header: Sequence[str]) -> str:
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in row) + "</tr>" for row in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def png_url(png: bytes) -> str:
    """PNG bytes as a ``data:`` URL."""
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def image_url(image: Tensor, scale: int = 2) -> str:
    """A ``(3, H, W)`` float image in [0, 1] as a PNG ``data:`` URL, enlarged ``scale``× nearest-neighbour."""
    array = unit_to_bytes(image).permute(1, 2, 0).numpy()
    picture = Image.fromarray(array)
    if scale > 1:
        picture = picture.resize((picture.width * scale, picture.height * scale), Image.NEAREST)
    buffer = io.BytesIO()
    picture.save(buffer, format="PNG")
    return png_url(buffer.getvalue())

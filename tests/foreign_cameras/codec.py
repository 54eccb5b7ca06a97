"""JPEG through PIL (libjpeg): the codec a camera's ISP or a web pipeline applies.

References: ITU-T T.81 (ISO/IEC 10918-1), the JPEG baseline standard.
"""

from __future__ import annotations

import io

import numpy as np
from PIL import Image

#: PIL's chroma subsampling codes: 0 is 4:4:4, 1 is 4:2:2, 2 is 4:2:0.
SUBSAMPLING = {"4:4:4": 0, "4:2:2": 1, "4:2:0": 2}


def jpeg_bytes(x: np.ndarray, quality: int, subsampling: str = "4:2:0") -> bytes:
    """The JPEG file of ``x`` (H, W, 3) in [0, 1], rounded to 8 bits, at ``quality`` (1–100)."""
    image = Image.fromarray(np.round(np.clip(x, 0.0, 1.0) * 255.0).astype(np.uint8))
    buffer = io.BytesIO()
    image.save(buffer, format="JPEG", quality=int(quality), subsampling=SUBSAMPLING[subsampling])
    return buffer.getvalue()


def jpeg(x: np.ndarray, quality: int, subsampling: str = "4:2:0") -> np.ndarray:
    """``x`` compressed and decoded again (float in [0, 1], on the 8-bit grid)."""
    with Image.open(io.BytesIO(jpeg_bytes(x, quality, subsampling))) as decoded:
        return np.asarray(decoded.convert("RGB"), dtype=np.float64) / 255.0

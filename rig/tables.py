"""Plain-text tables printed by the commands: the one formatter of a number cell."""
from __future__ import annotations

import math

__all__ = ["cell"]


def cell(v, width: int = 7, precision: int = 3) -> str:
    """``v`` right-aligned in ``width`` characters with ``precision`` decimals; ``-`` when it is None, not a number
    or not finite (a frame that was not scored, a figure with no frames)."""
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        return f"{'-':>{width}}"
    return f"{v:{width}.{precision}f}"

"""A terminal line chart of trace samples, drawn with braille dots (2 x 4 per character) in rich.

`render()` draws several series on one shared y axis: each sample is a column of dots joined to
its neighbour, so spikes and steps stay visible at any width. Where series overlap in a character,
the one listed later wins the colour.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

from rich.text import Text

COLOURS = ("cyan", "green", "red", "yellow", "magenta", "blue", "white")
_AXIS = 10  # characters of y-axis labels
# Braille dot bits by (column 0..1, row 0..3), rows counted from the top of the character.
_DOT = ((0x01, 0x02, 0x04, 0x40), (0x08, 0x10, 0x20, 0x80))


def render(series: Mapping[str, Sequence[float]], *, width: int = 80, height: int = 16,
           title: str = "") -> Text:
    """`series`: name -> values (same length, oldest first). width/height in characters, axis included."""
    cols = max(width - _AXIS - 1, 4)
    rows = max(height - 2, 2)  # a title line and a legend line
    values = [v for seq in series.values() for v in seq if math.isfinite(v)]
    low, high = (min(values), max(values)) if values else (0.0, 1.0)
    if high - low < 1e-9:
        low, high = low - 1.0, high + 1.0
    dots_x, dots_y = 2 * cols, 4 * rows
    bits = [[0] * cols for _ in range(rows)]
    owner = [[-1] * cols for _ in range(rows)]
    for index, seq in enumerate(series.values()):
        n = len(seq)
        previous = None
        for i, value in enumerate(seq):
            if not math.isfinite(value):
                previous = None  # a gap
                continue
            x = (i * (dots_x - 1)) // max(n - 1, 1)
            y = round((high - value) / (high - low) * (dots_y - 1))
            span = (y, y) if previous is None else (min(y, previous), max(y, previous))
            for yy in range(span[0], span[1] + 1):
                row, col = yy // 4, x // 2
                bits[row][col] |= _DOT[x % 2][yy % 4]
                owner[row][col] = index
            previous = y
    text = Text(title + "\n" if title else "\n", style="bold")
    for row in range(rows):
        label = f"{high:.4g}" if row == 0 else f"{low:.4g}" if row == rows - 1 else ""
        text.append(f"{label:>{_AXIS}}│")
        for col in range(cols):
            who = owner[row][col]
            style = COLOURS[who % len(COLOURS)] if who >= 0 else ""
            text.append(chr(0x2800 + bits[row][col]), style=style)
        text.append("\n")
    text.append(" " * _AXIS + " ")
    for index, (name, seq) in enumerate(series.items()):
        latest = f" {seq[-1]:.4g}" if len(seq) else ""
        text.append(f"━ {name}{latest}  ", style=COLOURS[index % len(COLOURS)])
    return text

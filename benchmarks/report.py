"""Printing: rich tables with a plain-text fallback."""

from __future__ import annotations

import math

try:
    from rich.console import Console
    from rich.table import Table

    _console = Console(width=220)
except ImportError:  # pragma: no cover - rich is in both venvs
    _console = None


def fmt(v, digits: int = 2) -> str:
    if v is None:
        return "—"
    if isinstance(v, str):
        return v
    if isinstance(v, (int,)) and not isinstance(v, bool):
        return str(v)
    if isinstance(v, float) and not math.isfinite(v):
        return "—"
    if isinstance(v, float):
        if abs(v) >= 100:
            return f"{v:.0f}"
        return f"{v:.{digits}f}"
    return str(v)


def print_table(title: str, columns: list[str], rows: list[list], note: str = "") -> None:
    cells = [[fmt(c) for c in r] for r in rows]
    if _console is None:
        print(f"\n== {title} ==")
        print(" | ".join(columns))
        for r in cells:
            print(" | ".join(r))
        if note:
            print(note)
        return
    t = Table(title=title, title_justify="left", caption=note or None, caption_justify="left")
    for i, c in enumerate(columns):
        t.add_column(c, justify="left" if i == 0 else "right")
    for r in cells:
        t.add_row(*r)
    _console.print(t)


def say(text: str) -> None:
    if _console is None:
        print(text)
    else:
        _console.print(text)

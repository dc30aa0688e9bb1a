"""The output of ``locnerf bench`` targets: a fixed-width table, or one JSON object per line.

A benchmark prints a ``# {settings}`` comment and a header line, then one row per measurement as
soon as it is measured; with ``--json`` every row is printed as ``settings | row`` on its own line.
Column order and names are the stable interface that lets two runs be compared line by line.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence


class BenchTable:
    """Prints benchmark rows as they come.

    Args:
        columns: row keys in print order; the first is left-aligned (the row's name).
        settings: what every row was measured with (map, device, threads, ...).
        as_json: print JSON lines instead of a table.
    """

    def __init__(self, columns: Sequence[str], settings: Mapping[str, object], as_json: bool) -> None:
        if not columns:
            raise ValueError("columns: expected at least one column name")
        self.columns = tuple(columns)
        self.settings = dict(settings)
        self.as_json = as_json
        self._widths = [max(22, len(self.columns[0]))] + [max(12, len(name)) for name in self.columns[1:]]
        if not as_json:
            print(f"# {json.dumps(self.settings)}")
            print(self._line(self.columns), flush=True)

    def _line(self, values: Sequence[object]) -> str:
        first, *rest = (str(value) for value in values)
        return " ".join([f"{first:<{self._widths[0]}}"] + [f"{text:>{width}}" for text, width in zip(rest, self._widths[1:])])

    def row(self, values: Mapping[str, object]) -> None:
        """Print one row; ``values`` must hold every column.

        Raises:
            ValueError: a column is missing from ``values``.
        """
        missing = [name for name in self.columns if name not in values]
        if missing:
            raise ValueError(f"benchmark row {dict(values)}: missing column(s) {missing}")
        if self.as_json:
            print(json.dumps(self.settings | dict(values)), flush=True)
        else:
            print(self._line([values[name] for name in self.columns]), flush=True)

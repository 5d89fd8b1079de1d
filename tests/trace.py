"""Reader of the traces and device logs of `hrt run` (docs/trace-format.md).

The column lists are parsed from the spec's tables, not written here, so that
docs/trace-format.md stays the single source: a file whose header differs from
the spec (a column added, dropped, renamed or moved) is refused, naming the
first difference.

    from trace import read_trace, read_device_log
    tr = read_trace(path)
    tr["fz"]          # numpy float64 array, one entry per row
    tr.columns        # the header, in order
    tr.units["fz"]    # "N", from the spec
    tr.pose("probe")  # (n, 7) array: x, y, z, qx, qy, qz, qw
"""

from __future__ import annotations

import pathlib

import numpy as np

SPEC = pathlib.Path(__file__).resolve().parent.parent / "docs" / "trace-format.md"
TRACE_SECTION = "## Trace columns"
DEVICE_LOG_SECTION = "## Device log columns"


def spec_table(section: str, spec: pathlib.Path = SPEC) -> list[tuple[str, str, str, str]]:
    """(column, unit, frame, meaning) of each row of the first table under `section`."""
    rows: list[tuple[str, str, str, str]] = []
    in_section = in_table = False
    seen = 0
    for line in spec.read_text(encoding="utf-8").splitlines():
        if line.startswith("## "):
            if in_section:
                break
            in_section = line.strip() == section
            continue
        if not in_section:
            continue
        if not line.startswith("|"):
            if in_table:
                break
            continue
        in_table = True
        seen += 1
        if seen <= 2:  # the table's header and its |---| line
            continue
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) < 4 or not (cells[0].startswith("`") and cells[0].endswith("`")):
            raise ValueError(f"{spec}: a row of '{section}' is not | `column` | unit | frame | meaning |: {line}")
        rows.append((cells[0].strip("`"), cells[1], cells[2], " | ".join(cells[3:])))
    if not rows:
        raise ValueError(f"{spec}: no column table under '{section}'")
    return rows


class Table:
    """The columns of one CSV file of the spec, as float64 arrays."""

    def __init__(self, path: pathlib.Path, columns: list[str], units: dict[str, str], data: np.ndarray):
        self.path = path
        self.columns = columns
        self.units = units
        self._data = data  # shape (rows, columns)
        self._index = {c: i for i, c in enumerate(columns)}

    def __len__(self) -> int:
        return self._data.shape[0]

    def __contains__(self, name: str) -> bool:
        return name in self._index

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self._data[:, self._index[name]]
        except KeyError:
            raise KeyError(f"{self.path}: no column '{name}' (columns: {', '.join(self.columns)})") from None

    def as_dict(self) -> dict[str, np.ndarray]:
        return {c: self[c] for c in self.columns}

    def pose(self, prefix: str) -> np.ndarray:
        """(rows, 7): <prefix>_x, _y, _z, _qx, _qy, _qz, _qw (a pose per row)."""
        return np.column_stack([self[f"{prefix}_{k}"] for k in ("x", "y", "z", "qx", "qy", "qz", "qw")])

    def wrench(self, prefix: str = "") -> np.ndarray:
        """(rows, 6): force and torque; prefix "" is the device's (fx..tz), else contact, friction, ..."""
        p = f"{prefix}_" if prefix else ""
        return np.column_stack([self[p + k] for k in ("fx", "fy", "fz", "tx", "ty", "tz")])


def _read(path, section: str, spec: pathlib.Path) -> Table:
    path = pathlib.Path(path)
    table = spec_table(section, spec)
    expected = [r[0] for r in table]
    units = {r[0]: r[1] for r in table}
    with open(path, encoding="ascii") as f:
        header = f.readline().rstrip("\n")
        columns = header.split(",")
        if columns != expected:
            for i, (got, want) in enumerate(zip(columns, expected)):
                if got != want:
                    raise ValueError(f"{path}: column {i} is '{got}', {spec.name} says '{want}'")
            raise ValueError(
                f"{path}: the header has {len(columns)} columns, {spec.name} ('{section}') lists {len(expected)}"
            )
        rows = []
        for lineno, line in enumerate(f, start=2):
            fields = line.rstrip("\n").split(",")
            if len(fields) != len(expected):
                raise ValueError(f"{path}: line {lineno}: {len(fields)} fields, the header has {len(expected)}")
            try:
                rows.append([float(x) for x in fields])
            except ValueError as e:
                raise ValueError(f"{path}: line {lineno}: {e}") from None
    data = np.array(rows, dtype=np.float64).reshape(len(rows), len(expected))
    return Table(path, expected, units, data)


def read_trace(path, spec: pathlib.Path = SPEC) -> Table:
    """A trace of `hrt run` (one row per simulation frame)."""
    return _read(path, TRACE_SECTION, spec)


def read_device_log(path, spec: pathlib.Path = SPEC) -> Table:
    """A device log of `hrt run` (one row per device tick)."""
    return _read(path, DEVICE_LOG_SECTION, spec)


if __name__ == "__main__":  # python tests/trace.py TRACE.csv: a one-line summary per column
    import sys

    for p in sys.argv[1:]:
        t = read_trace(p)
        print(f"{p}: {len(t)} rows")
        for c in t.columns:
            v = t[c]
            print(f"  {c:>14} [{t.units[c]}]  min {v.min() if len(v) else 0:.6g}  max {v.max() if len(v) else 0:.6g}")

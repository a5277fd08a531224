"""
Numeric columns from the project's CSV files: segment tables, volume histories, measured curves.

All of them share one format: an optional block of ``#`` comment lines (provenance), a header
row naming the columns (extra columns are allowed), then rows of numbers. Every problem is
reported as one line that starts with the file name and names the row and column.
"""

import csv
import math
from pathlib import Path
from typing import Sequence

import numpy as np
from numpy.typing import NDArray


def read_columns(path: str | Path, columns: Sequence[str], error: type[ValueError],
                 what: str) -> dict[str, NDArray[np.float64]]:
    """
    The named columns of a CSV file as float arrays, in file order.

    ``error`` is the exception class to raise and ``what`` names the file's role in messages
    ("segment table", "volume history"). Values must be finite; at least one row is needed.
    """
    path = Path(path)
    try:
        # utf-8-sig: spreadsheets save "CSV UTF-8" with a byte-order mark before the header.
        text = path.read_text(encoding='utf-8-sig')
    except OSError as err:
        raise error(f'{path}: cannot read the {what} ({err.strerror})') from None
    except UnicodeDecodeError as err:
        raise error(f'{path}: the {what} is not UTF-8 text (byte {err.start}); save it as '
                    'CSV UTF-8') from None
    lines = [line for line in text.splitlines()
             if line.strip() and not line.lstrip().startswith('#')]
    if not lines:
        raise error(f'{path}: empty {what}, expected a header with {",".join(columns)}')
    reader = csv.reader(lines)
    header = [name.strip() for name in next(reader)]
    missing = [name for name in columns if name not in header]
    if missing:
        raise error(f'{path}: no column {", ".join(missing)} in the header '
                    f'({",".join(header)}); expected {",".join(columns)}')
    index = {name: header.index(name) for name in columns}
    values: dict[str, list[float]] = {name: [] for name in columns}
    for row_number, row in enumerate(reader, start=1):
        for name, i in index.items():
            cell = row[i].strip() if i < len(row) else ''
            try:
                value = float(cell)
            except ValueError:
                raise error(f'{path}: row {row_number}, column {name}: not a number: '
                            f'{cell or "<missing>"!r}') from None
            if not math.isfinite(value):
                raise error(f'{path}: row {row_number}, column {name}: must be finite, '
                            f'got {cell}') from None
            values[name].append(value)
    if not values[columns[0]]:
        raise error(f'{path}: no rows below the header')
    return {name: np.asarray(column, dtype=float) for name, column in values.items()}

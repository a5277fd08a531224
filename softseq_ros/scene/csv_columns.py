"""
Numeric columns from the project's CSV files: segment tables, volume histories, measured curves.

And the one writer of a solved path's rows (:func:`write_rows`), in the same format.

All of them share one format: an optional block of ``#`` comment lines (provenance), a header
row naming the columns (extra columns are allowed), then rows of numbers. Every problem is
reported as one line that starts with the file name and names the row and column.
"""

import csv
import math
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np
from numpy.typing import NDArray

from softseq_ros.errors import NotRegularFileError, read_regular_file


def read_rows(path: str | Path, error: type[ValueError], what: str,
              expected: Sequence[str]) -> tuple[list[str], list[str], list[list[str]]]:
    """
    A CSV file of the common format: its comment lines, header (stripped) and data rows.

    ``expected`` names the columns shown in the message for an empty file.
    """
    path = Path(path)
    try:
        # utf-8-sig: spreadsheets save "CSV UTF-8" with a byte-order mark before the header.
        # Read only as a regular file: a FIFO would wait for a writer that never comes.
        text = read_regular_file(path).decode('utf-8-sig')
    except NotRegularFileError as err:
        raise error(f'{path}: the {what} is {err.kind}, not a regular file') from None
    except OSError as err:
        raise error(f'{path}: cannot read the {what} ({err.strerror})') from None
    except UnicodeDecodeError as err:
        raise error(f'{path}: the {what} is not UTF-8 text (byte {err.start}); save it as '
                    'CSV UTF-8') from None
    lines = text.splitlines()
    comments = [line for line in lines if line.lstrip().startswith('#')]
    data = [line for line in lines if line.strip() and not line.lstrip().startswith('#')]
    if not data:
        raise error(f'{path}: empty {what}, expected a header with {",".join(expected)}')
    reader = csv.reader(data)
    try:
        header = [name.strip() for name in next(reader)]
        return comments, header, list(reader)
    except csv.Error as err:
        # A field beyond csv.field_size_limit() (or a stray quote): no number is that long.
        raise error(f'{path}: line {reader.line_num} of the data: not a CSV row of numbers '
                    f'({err})') from None


def numeric_columns(path: str | Path, header: list[str], rows: list[list[str]],
                    columns: Sequence[str], error: type[ValueError],
                    allow_nan: Sequence[str] = ()) -> dict[str, NDArray[np.float64]]:
    """
    The named columns (all in ``header``) of ``rows`` as float arrays.

    Values must be finite, except a literal ``nan`` in a column of ``allow_nan`` (a frame
    without a measurement); the message names the row and the column.
    """
    index = {name: header.index(name) for name in columns}
    values: dict[str, list[float]] = {name: [] for name in columns}
    for row_number, row in enumerate(rows, start=1):
        for name, i in index.items():
            cell = row[i].strip() if i < len(row) else ''
            try:
                value = float(cell)
            except ValueError:
                raise error(f'{path}: row {row_number}, column {name}: not a number: '
                            f'{cell or "<missing>"!r}') from None
            if not math.isfinite(value) and not (name in allow_nan and cell.lower() == 'nan'):
                raise error(f'{path}: row {row_number}, column {name}: must be finite, '
                            f'got {cell}') from None
            values[name].append(value)
    return {name: np.asarray(column, dtype=float) for name, column in values.items()}


def read_columns(path: str | Path, columns: Sequence[str], error: type[ValueError],
                 what: str, optional: Sequence[str] = ()) -> dict[str, NDArray[np.float64]]:
    """
    The named columns of a CSV file as float arrays, in file order.

    ``error`` is the exception class to raise and ``what`` names the file's role in messages
    ("segment table", "volume history"). Values must be finite; at least one row is needed.
    The ``optional`` columns are read too where the header has them.
    """
    _, header, rows = read_rows(path, error, what, columns)
    missing = [name for name in columns if name not in header]
    if missing:
        raise error(f'{path}: no column {", ".join(missing)} in the header '
                    f'({",".join(header)}); expected {",".join(columns)}')
    if not rows:
        raise error(f'{path}: no rows below the header')
    present = [name for name in optional if name in header]
    return numeric_columns(path, header, rows, (*columns, *present), error)


def write_rows(path: str | Path, header: Sequence[str],
               rows: Iterable[tuple[Sequence[float], str]]) -> None:
    """
    A solved path's CSV: ``header``, then per row its numbers (exact: repr) and its event.

    The folder is made when missing. The quasi-static and the dynamic paths both write so.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open('w', newline='') as handle:
        writer = csv.writer(handle)
        writer.writerow(header)
        for numbers, event in rows:
            writer.writerow([*(repr(float(x)) for x in numbers), event])

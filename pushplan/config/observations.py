"""Observation files: the commands a robot executed and what it observed after each.

One row per executed command, in order from the undeformed block (the press first,
as in ``plan.json``'s ``commands``).  Columns (SI units, degrees for angles):

=================  ========  =====================================================
column             unit      meaning
=================  ========  =====================================================
``dx, dy, dz``     m         upper-face translation increment (the command)
``dtheta_deg``     deg       upper-face rotation increment about z (the command)
``lower_x``        m         lower-face centroid displacement from rest, world x
``lower_y``        m         ... world y (``lower_centroid`` in ``summary.json``)
``lower_yaw_deg``  deg       lower-face yaw (``lower_yaw_deg`` in ``summary.json``)
``force_x, _y, _z``  N       force the gripper applies on the block, world frame
                             (what a wrist F/T sensor reads, ``upper_force`` of
                             ``summary.json``; a press has force_z < 0)
=================  ========  =====================================================

The four command columns are required; any of the observed columns may be left out
(a pose-only or force-only experiment), but a column that is present must hold a
finite number in every row.  The CSV form has one header line naming the columns
(any order; lines starting with ``#`` before it are comments) and one line per
command; the JSON form is ``{"observations": [{column: value, ...}, ...]}`` with
the same keys in every row.  Both forms read into the same :class:`Observations`;
:func:`read_observations` chooses by the file suffix (``.csv`` or ``.json``).
Every error is an :class:`~pushplan.errors.InputError` naming the file, row and column.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fe_contact import Command

from ..errors import InputError
from ..limits import MAX_OBSERVATION_ROWS
from .commands import COMMAND_KEYS, MAX_TURN_DEG, command_to_dict
from .files import read_json, read_text
from .validate import short, number

POSE_COLUMNS = ("lower_x", "lower_y", "lower_yaw_deg")
FORCE_COLUMNS = ("force_x", "force_y", "force_z")
OBSERVED_COLUMNS = POSE_COLUMNS + FORCE_COLUMNS
ALL_COLUMNS = COMMAND_KEYS + OBSERVED_COLUMNS
SUFFIXES = (".csv", ".json")


@dataclass(frozen=True)
class Observations:
    """Executed commands and the observed columns after each (SI units, yaw in degrees).

    Attributes
    ----------
    commands : tuple of fe_contact.Command
        The K executed commands (m, rad).
    values : dict of str -> ndarray, shape (K,)
        The observed columns present, keyed by their names in :data:`OBSERVED_COLUMNS`.
    """

    commands: tuple[Command, ...]
    values: dict

    def __post_init__(self):
        object.__setattr__(self, "values", dict(self.values))  # the caller's dict is not changed
        if not self.commands:
            raise InputError("observations: no rows (at least one executed command is needed)")
        for name, v in self.values.items():
            if name not in OBSERVED_COLUMNS:
                raise InputError(f"observations: unknown column {name!r} (allowed: {', '.join(ALL_COLUMNS)})")
            a = np.asarray(v, float)
            if a.shape != (len(self.commands),):
                raise InputError(f"observations: column {name} has {a.size} values for {len(self.commands)} rows")
            if not np.all(np.isfinite(a)):
                row = int(np.flatnonzero(~np.isfinite(a))[0])
                raise InputError(f"observations: row {row + 1} column {name} must be finite, got {a[row]!r}")
            self.values[name] = a

    @property
    def columns(self) -> tuple[str, ...]:
        """The observed columns present, in the order of :data:`OBSERVED_COLUMNS`."""
        return tuple(c for c in OBSERVED_COLUMNS if c in self.values)

    def __len__(self) -> int:
        return len(self.commands)

    def rows(self) -> list[dict]:
        """One dict per command: the command's four keys, then the observed columns."""
        return [{**command_to_dict(c), **{k: float(self.values[k][i]) for k in self.columns}}
                for i, c in enumerate(self.commands)]


def leading_press(obs: Observations) -> tuple[Command, ...]:
    """The leading rows of ``obs`` that move the upper face only vertically (the press)."""
    out = []
    for c in obs.commands:
        if c.dx or c.dy or c.dtheta:
            break
        out.append(c)
    return tuple(out)


def observations_to_csv(obs: Observations) -> str:
    """The CSV form (floats written exactly: ``repr`` round-trips)."""
    out = io.StringIO()
    names = COMMAND_KEYS + obs.columns
    out.write(",".join(names) + "\n")
    for row in obs.rows():
        out.write(",".join(repr(float(row[k])) for k in names) + "\n")
    return out.getvalue()


def observations_to_json(obs: Observations) -> dict:
    """The JSON form."""
    return {"observations": obs.rows()}


def _number(where: str, text) -> float:
    if isinstance(text, str):
        try:
            v = float(text)
        except ValueError:
            raise InputError(f"{where} must be a number, got {short(text)}") from None
    elif isinstance(text, (int, float)) and not isinstance(text, bool):
        return number(where, text)  # an integer beyond a float's range named, not an OverflowError
    else:
        raise InputError(f"{where} must be a number, got {short(text)}")
    if not math.isfinite(v):
        raise InputError(f"{where} must be finite, got {short(text)}")
    return v


def _check_header(names, where: str) -> None:
    for k in names:
        if k not in ALL_COLUMNS:
            raise InputError(f"{where}: unknown column {k!r} (allowed: {', '.join(ALL_COLUMNS)})")
    if len(set(names)) != len(names):
        raise InputError(f"{where}: a column appears twice in {list(names)}")
    for k in COMMAND_KEYS:
        if k not in names:
            raise InputError(f"{where}: missing column {k} (the command columns {', '.join(COMMAND_KEYS)} "
                             "are required)")


def observations_from_table(names, rows, where: str) -> Observations:
    """Observations from column ``names`` and ``rows`` of values (strings or numbers);
    ``where`` names the source in messages (row numbers count data rows from 1)."""
    names = tuple(names)
    _check_header(names, where)
    if not rows:
        raise InputError(f"{where}: no rows (at least one executed command is needed)")
    if len(rows) > MAX_OBSERVATION_ROWS:
        raise InputError(f"{where}: {len(rows)} rows, more than {MAX_OBSERVATION_ROWS}")
    data = np.empty((len(rows), len(names)))
    for i, row in enumerate(rows):
        if len(row) != len(names):
            raise InputError(f"{where}: row {i + 1} has {len(row)} values, the header {len(names)}")
        for j, (k, text) in enumerate(zip(names, row, strict=True)):
            data[i, j] = _number(f"{where}: row {i + 1} column {k}", text)
    col = {k: data[:, j] for j, k in enumerate(names)}
    turns = np.flatnonzero(np.abs(col["dtheta_deg"]) >= MAX_TURN_DEG)
    if turns.size:
        raise InputError(f"{where}: row {turns[0] + 1} column dtheta_deg must be in (-{MAX_TURN_DEG:g}, "
                         f"{MAX_TURN_DEG:g}) deg (one step's turn), got {col['dtheta_deg'][turns[0]]!r}")
    commands = tuple(Command(float(a), float(b), float(c), math.radians(float(d)))
                     for a, b, c, d in zip(*(col[k] for k in COMMAND_KEYS), strict=True))
    return Observations(commands, {k: col[k] for k in OBSERVED_COLUMNS if k in col})


def parse_csv(text: str, where: str = "observations") -> Observations:
    """Read the CSV form (see the module docstring)."""
    table = []
    reader = csv.reader(io.StringIO(text, newline=""), skipinitialspace=True)
    try:  # the whole text through the CSV reader: a quoted field may hold a line break (then it is no number)
        for row in reader:
            if not any(cell.strip() for cell in row) or row[0].lstrip().startswith("#"):
                continue
            table.append(row)
            if len(table) > MAX_OBSERVATION_ROWS + 1:
                raise InputError(f"{where}: more than {MAX_OBSERVATION_ROWS} rows")
    except csv.Error as exc:  # a field over the reader's limit, a NUL byte
        raise InputError(f"{where}: malformed CSV at line {reader.line_num}: {exc}") from None
    if not table:
        raise InputError(f"{where}: empty (expected a header line and one line per command)")
    return observations_from_table([h.strip() for h in table[0]], table[1:], where)


def parse_json(data, where: str = "observations") -> Observations:
    """Read the JSON form (see the module docstring)."""
    if not isinstance(data, dict) or set(data) != {"observations"} or not isinstance(data["observations"], list):
        raise InputError(f"{where}: expected an object with one key 'observations' holding a list of rows")
    items = data["observations"]
    if not items:
        raise InputError(f"{where}: no rows (at least one executed command is needed)")
    if len(items) > MAX_OBSERVATION_ROWS:
        raise InputError(f"{where}: {len(items)} rows, more than {MAX_OBSERVATION_ROWS}")
    for i, item in enumerate(items):
        if not isinstance(item, dict):
            raise InputError(f"{where}: row {i + 1} must be an object, got {short(item)}")
    names = tuple(items[0])
    for i, item in enumerate(items):
        if tuple(item) != names and set(item) != set(names):
            raise InputError(f"{where}: row {i + 1} has columns {sorted(item)}, row 1 {sorted(names)}")
    return observations_from_table(names, [[item[k] for k in names] for item in items], where)


def observation_format(path) -> str:
    """``"csv"`` or ``"json"`` from the suffix of ``path``.

    Raises
    ------
    InputError
        Any other suffix.
    """
    suffix = Path(path).suffix.lower()
    if suffix not in SUFFIXES:
        raise InputError(f"observation file {path} must end in .csv or .json, got {suffix or 'no suffix'!r}")
    return suffix[1:]


def read_observations(path) -> Observations:
    """Read an observation file (CSV or JSON by its suffix).

    Raises
    ------
    InputError
        Missing or unreadable file, empty, unknown or missing column, a row of the
        wrong length, a value that is not a finite number (file, row and column named).
    """
    path = Path(path)
    if observation_format(path) == "json":
        return parse_json(read_json(path, "observation"), str(path))
    return parse_csv(read_text(path, "observation"), str(path))


def encode_observations(obs: Observations, path) -> bytes:
    """The bytes of ``obs`` in the format of ``path``'s suffix."""
    import json

    if observation_format(path) == "json":
        return (json.dumps(observations_to_json(obs), indent=1) + "\n").encode()
    return observations_to_csv(obs).encode()

"""Tabular data files: strict CSV reading with line-numbered errors, and atomic writing.

Every reading problem raises `InputError` naming the file, the row (its line number in the file,
header = line 1) and the column, so the CLI can report it in one line. Writers never leave a
half-written file: they write a temporary file beside the target and rename it over the target
(through a symbolic link: over the link's target, keeping the link). Character devices and named
pipes are written to in place; sockets, block devices and directories are refused (`output_target`).
"""

from __future__ import annotations

import csv
import errno
import math
import os
import re
import secrets
import stat
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np

from ctrplan.base.errors import InputError


def joint_names(n_tubes: int) -> tuple[str, ...]:
    """``(beta1 … betaN, alpha1 … alphaN)``: joint and CSV column names for N tubes."""
    tubes = range(1, n_tubes + 1)
    return tuple(f"beta{i}" for i in tubes) + tuple(f"alpha{i}" for i in tubes)


def tip_names(n_tubes: int) -> tuple[str, ...]:
    """Tip columns of the measured-data format (mm, robot frame): tip1_x … tipN_z."""
    return tuple(f"tip{i}_{a}" for i in range(1, n_tubes + 1) for a in "xyz")


#: Tip columns of a three-tube robot.
TIP_NAMES = tip_names(3)
#: A joint or tip column and its tube number: ``beta3``, ``alpha3``, ``tip3_x``.
TUBE_COLUMN = re.compile(r"^(beta|alpha)(\d+)$|^tip(\d+)_[xyz]$")


@dataclass(frozen=True)
class Table:
    """Numeric columns read from a CSV file.

    Attributes:
        path: the file.
        columns: names of the columns in ``values``, in the order asked for.
        values: (R, C) float array, all finite.
        lines: (R,) line number of each row in the file (header = line 1).
        labels: text columns asked for and present, name -> (R,) strings (e.g. a measurement session).
    """

    path: Path
    columns: tuple[str, ...]
    values: np.ndarray
    lines: np.ndarray
    labels: dict[str, np.ndarray] = field(default_factory=dict)

    def column(self, name: str) -> np.ndarray:
        """One column (R,)."""
        return self.values[:, self.columns.index(name)]

    @property
    def joints(self) -> np.ndarray:
        """Joint columns (R, 2N) in the order beta1..betaN, alpha1..alphaN (mm, rad)."""
        n = sum(c.startswith("beta") for c in self.columns)
        return self.values[:, [self.columns.index(c) for c in joint_names(n)]]


#: Cells a reader that allows missing values reads as NaN (compared in lower case).
MISSING_CELLS = frozenset({"", "nan", "na", "n/a", "null", "none"})


def read_text(path: str | Path) -> str:
    """The text of the data file ``path`` (UTF-8, a leading byte-order mark dropped).

    Raises `InputError` naming the file if it is missing, a directory or unreadable.
    """
    path = Path(path)
    try:
        return path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise InputError(f"{path}: file not found") from None
    except IsADirectoryError:
        raise InputError(f"{path}: is a directory, expected a CSV file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read ({exc})") from None


def parse_number(cell: str, path: str | Path, line: int, name: str, *,
                 allow_missing: bool = False) -> float:
    """The number in ``cell`` (field ``name`` on line ``line`` of ``path``, for messages).

    Raises `InputError` for text that is not a number and, unless ``allow_missing``, for a
    non-finite number. With ``allow_missing`` a `MISSING_CELLS` cell reads as NaN and non-finite
    numbers are returned: the caller checks them.
    """
    cell = cell.strip()
    try:
        if "_" in cell:  # float() reads "1_0" as 10
            raise ValueError(cell)
        value = float(cell)
    except ValueError:
        if allow_missing and cell.lower() in MISSING_CELLS:
            return math.nan
        raise InputError(f"{path}: row {line}: {name} = {cell!r} is not a number") from None
    if not allow_missing and not math.isfinite(value):
        raise InputError(f"{path}: row {line}: {name} = {cell!r} is not a finite number")
    return value


def read_table(path: str | Path, columns: Sequence[str], *, optional: Sequence[str] = (),
               allow_missing: bool = False, n_tubes: int | None = None, labels: Sequence[str] = ()) -> Table:
    """Read the named numeric ``columns`` of a CSV file with a header line; other columns are ignored.

    ``optional`` columns are read too when the header has them: ``Table.columns`` is ``columns``
    followed by the optional ones found. Blank lines (also before the header) are skipped. Raises
    `InputError` for a missing or empty file, a header without data rows, a missing or repeated
    column, a row with more or fewer fields than the header, or a cell that is not a finite number (see
    `parse_number` for ``allow_missing``). With ``n_tubes``, a joint or tip column of a tube beyond
    the robot's ``n_tubes`` (``beta3``, ``alpha3``, ``tip3_x`` for two tubes) is an error too: the data
    are for another robot.
    """
    path = Path(path)
    return parse_table(read_text(path), path, columns, optional=optional, allow_missing=allow_missing,
                       n_tubes=n_tubes, labels=labels)


def parse_table(text: str, path: str | Path, columns: Sequence[str], *, optional: Sequence[str] = (),
                allow_missing: bool = False, n_tubes: int | None = None, labels: Sequence[str] = ()) -> Table:
    """`read_table` on the already read ``text`` of ``path``; ``labels``: optional text columns, read as
    they are (a cell must not be empty)."""
    path = Path(path)
    reader = csv.reader(text.splitlines())
    header = next((cells for cells in reader if any(c.strip() for c in cells)), None)
    if header is None:
        raise InputError(f"{path}: empty file (expected a header line: {','.join(columns)})")
    head = reader.line_num
    names = [h.strip() for h in header]
    extra = [] if n_tubes is None else [h for h in names if (m := TUBE_COLUMN.match(h)) and
                                        int(m.group(2) or m.group(3)) > n_tubes]
    if extra:
        raise InputError(f"{path}: row {head}: column{'s' if len(extra) > 1 else ''} {', '.join(extra)} "
                         f"belong{'' if len(extra) > 1 else 's'} to a tube the robot does not have (it has "
                         f"{n_tubes}); give the robot the data were measured with (--robot R.yaml)")
    missing = [c for c in columns if c not in names]
    if missing:
        raise InputError(f"{path}: row {head}: missing column{'s' if len(missing) > 1 else ''} "
                         f"{', '.join(repr(m) for m in missing)} (header has: {','.join(names)})")
    wanted = list(columns) + [c for c in optional if c in names and c not in columns]
    index = []
    for name in wanted:
        hits = [i for i, h in enumerate(names) if h == name]
        if len(hits) > 1:
            raise InputError(f"{path}: row {head}: column {name!r} appears {len(hits)} times")
        index.append(hits[0])
    text_at = {name: names.index(name) for name in labels if name in names}
    values, lines, texts = [], [], {name: [] for name in text_at}
    for cells in reader:
        if not any(c.strip() for c in cells):
            continue
        line = reader.line_num
        if len(cells) != len(names):  # a cell too many or too few: the columns may have shifted
            raise InputError(f"{path}: row {line}: expected {len(names)} fields (as the header), "
                             f"got {len(cells)}")
        values.append([parse_number(cells[i], path, line, name, allow_missing=allow_missing)
                       for name, i in zip(wanted, index, strict=True)])
        for name, i in text_at.items():
            if not cells[i].strip():
                raise InputError(f"{path}: row {line}: {name} is empty")
            texts[name].append(cells[i].strip())
        lines.append(line)
    if not values:
        raise InputError(f"{path}: no data rows after the header")
    return Table(path=path, columns=tuple(wanted), values=np.array(values, dtype=float),
                 lines=np.array(lines, dtype=np.int64), labels={k: np.array(v) for k, v in texts.items()})


def output_dir(path: str | Path, option: str = "--out") -> Path:
    """Create the output directory ``path`` (and its parents) if needed; return it as a `Path`.

    Raises `InputError` naming ``option`` if ``path`` (or a parent) is a file or cannot be created.
    """
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        raise InputError(f"{option}: {path} exists and is not a directory") from None
    except OSError as exc:
        raise InputError(f"{option}: cannot create {path} ({exc.strerror})") from None
    return path


def check_output_dir(path: str | Path, option: str = "--out") -> Path:
    """Refuse, before any work, an output directory that `output_dir` could not create (an
    `InputError` naming ``option``): the missing folders are made to prove it and removed again, so
    a command that then fails or is interrupted leaves none behind. Returns ``path`` as a `Path`."""
    path = Path(path)
    missing = [p for p in (path, *path.parents) if not p.exists()]  # deepest first
    output_dir(path, option)
    for folder in missing:
        folder.rmdir()
    return path


#: errno values of a failed write (a full disk or device, a closed pipe, ...): a one-line error.
WRITE_ERRORS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EPIPE, errno.EIO, errno.EROFS})


def output_target(path: str | Path) -> tuple[Path, bool]:
    """Where writing ``path`` goes, and whether it is streamed: ``(file, False)`` for a regular file
    or a new name -- ``file`` is the path with every symbolic link resolved, so that writing through a
    link replaces the link's target and keeps the link -- or ``(path, True)`` for a character device
    (``/dev/null``, a terminal) or a named pipe, which are written to in place, never replaced.

    Raises `InputError` naming ``path`` for a directory, a socket, a block device, a symbolic-link
    loop or a path that cannot be looked at.
    """
    path = Path(path)
    try:
        mode = os.stat(path).st_mode  # follows symbolic links
    except FileNotFoundError:  # a new file, or a link to a file not there yet
        return Path(os.path.realpath(path)), False
    except OSError as exc:
        raise InputError(f"{path}: cannot write ({exc.strerror})") from None
    if stat.S_ISREG(mode):
        return Path(os.path.realpath(path)), False
    if stat.S_ISCHR(mode) or stat.S_ISFIFO(mode):
        return path, True
    kind = {stat.S_IFDIR: "a directory", stat.S_IFSOCK: "a socket", stat.S_IFBLK: "a block device"}
    raise InputError(f"{path}: is {kind.get(stat.S_IFMT(mode), 'not a regular file')}, expected a file name "
                     f"(ctrplan writes files, character devices such as /dev/null and named pipes)")


@contextmanager
def atomic_write(path: str | Path, mode: str = "w") -> Iterator[IO]:
    """Open a temporary file beside ``path``; rename it onto ``path`` only if the block succeeds.

    Through a symbolic link the link's target is replaced and the link kept; a character device or
    a named pipe is written to directly, without a temporary file (`output_target`). Raises
    `InputError` if the target cannot be a file, its directory does not exist or cannot be written,
    or the writing fails for want of space or a reader (`WRITE_ERRORS`). The file gets the usual
    permissions (0666 less the umask).
    """
    target, stream = output_target(path)
    kwargs = {} if "b" in mode else {"encoding": "utf-8", "newline": ""}
    if stream:
        # in place: O_TRUNC does nothing to a device or a pipe
        with _write_errors(path), open(target, mode, **kwargs) as fh:
            yield fh
        return
    if not target.parent.is_dir():
        raise InputError(f"{path}: output directory {str(target.parent)!r} does not exist")
    tmp = target.parent / f".{target.name}.{secrets.token_hex(4)}.tmp"
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    except OSError as exc:
        raise InputError(f"{path}: cannot write ({exc.strerror})") from None
    try:
        with _write_errors(path), os.fdopen(fd, mode, **kwargs) as fh:
            yield fh
        os.replace(tmp, target)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


@contextmanager
def _write_errors(path: str | Path) -> Iterator[None]:
    """`WRITE_ERRORS` raised in the block (or when its file is closed) as an `InputError` naming
    ``path``."""
    try:
        yield
    except OSError as exc:
        if exc.errno not in WRITE_ERRORS:
            raise
        raise InputError(f"{path}: cannot write ({exc.strerror})") from None


def save_figure(fig: Any, path: str | Path, **kwargs: Any) -> Path:
    """``fig.savefig`` (matplotlib) to ``path`` through `atomic_write`, in the format of its suffix
    (PNG without one); returns ``path``."""
    path = Path(path)
    with atomic_write(path, "wb") as fh:
        fig.savefig(fh, format=path.suffix[1:] or "png", **kwargs)
    return path


def format_csv(header: Sequence[str] | None, rows: np.ndarray, formats: Sequence[str]) -> str:
    """CSV text: a header line (none if ``header`` is None), then ``rows`` (R, C) with one %-format
    per column (``"%r"`` writes a float exactly)."""
    lines = [] if header is None else [",".join(header)]
    fmt = ",".join(formats)
    lines.extend(fmt % tuple(r) for r in rows.tolist())
    return "\n".join(lines) + "\n"


def plain(obj: Any) -> Any:
    """``obj`` as plain JSON/YAML values: numpy scalars and arrays become Python numbers and lists,
    tuples lists, mapping keys strings, and non-finite floats None (JSON has no NaN)."""
    if isinstance(obj, dict):
        return {str(k): plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, np.ndarray)):
        return [plain(v) for v in obj]
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    return obj

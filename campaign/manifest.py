"""The campaign manifest: test points, their flight condition, a priori model, runs and method.

Two forms, read into the same :class:`Campaign`:

* TOML: a ``[campaign]`` table (``name``, ``method``, ``refine``, ``condition``, ``prior``
  (``"stitch"``: :mod:`campaign.prior`), and defaults
  every point inherits: ``profile``, ``channel_map``), an optional ``[options]`` table of
  estimator options (plain numbers, strings, booleans) and one ``[[point]]`` table per test point;
  ``matrix = "points.csv"`` in ``[campaign]`` reads the points from a CSV test matrix instead.
* a CSV test matrix on its own (``campaign identify points.csv --method ml``): one row per point.

A point has a ``name`` (CSV column ``point``), ``runs`` (files or glob patterns, any format
``identify`` reads; in CSV separated by ``;``), optionally ``validate`` (held-out runs, same
form), ``profile`` (a profile file or bundled name; a *scheduled* profile, whose derivatives are
tables over the condition, is evaluated at the point's condition) and ``channel_map``. Every
other field is a condition column (airspeed, altitude, mass, ..., free names); those named
``trim_<channel>`` are the point's trim values. Paths are relative to the manifest's folder.
Nothing in a manifest is evaluated as code: values are only numbers, strings and booleans.
"""
from __future__ import annotations

import csv
import glob
import io
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from identify.errors import read_text
from identify.estimators.registry import METHOD_NAMES

from identify.errors import CampaignError

POINT_KEYS = {"name", "runs", "validate", "profile", "channel_map"}
CAMPAIGN_KEYS = {"name", "method", "refine", "condition", "profile", "channel_map", "matrix", "prior"}
PRIORS = ("stitch",)  # [campaign] prior: each point's prior the stitched model of the others (campaign.prior)
TRIM = "trim_"
FILE_SUFFIXES = (".csv", ".mat", ".toml", ".json", ".txt")


@dataclass(frozen=True)
class Point:
    """One test point: ``condition`` {column: number or text}, ``trim`` {channel: value},
    ``runs``/``validate`` patterns as written (relative to ``root``)."""

    name: str
    condition: dict
    runs: tuple[str, ...] = ()
    validate: tuple[str, ...] = ()
    profile: str | None = None
    channel_map: str | None = None
    trim: dict = field(default_factory=dict)
    root: str = "."

    def files(self, which: str = "runs") -> list[Path]:
        """The run files of ``runs`` or ``validate``: each pattern expanded (sorted), relative to
        the manifest's folder; a pattern that matches nothing is a :class:`CampaignError`."""
        if which == "runs" and not self.runs:
            raise CampaignError(f"point {self.name}: no runs listed")
        out = []
        for pattern in getattr(self, which):
            path = (Path(self.root) / pattern).resolve()  # absolute: a worker may run elsewhere
            if glob.has_magic(str(path)):
                found = sorted(Path(p) for p in glob.glob(str(path)))
                if not found:
                    raise CampaignError(f"point {self.name}: no file matches '{pattern}'")
                out += found
            elif path.is_file():
                out.append(path)
            else:
                raise CampaignError(f"point {self.name}: no such run file '{pattern}'")
        return out

    def profile_path(self) -> str:
        """The profile as the identify loaders take it: a path relative to the manifest, or a
        bundled profile's name."""
        path = Path(self.root) / self.profile
        return str(path) if path.exists() else self.profile


@dataclass(frozen=True)
class Campaign:
    name: str
    points: tuple[Point, ...]
    method: str = "ml"
    refine: bool = False
    condition: str | None = None
    options: dict = field(default_factory=dict)
    source: str = "<manifest>"
    prior: str | None = None  # "stitch": a second pass, each point with the others' stitched model as prior

    @property
    def condition_columns(self) -> list[str]:
        """Every condition column of any point, in first-seen order."""
        seen = {}
        for p in self.points:
            seen.update(dict.fromkeys(p.condition))
        return list(seen)

    @property
    def trend_condition(self) -> str:
        """The condition trends and stitching run over: ``condition``, else the first numeric column."""
        if self.condition:
            return self.condition
        for c in self.condition_columns:
            if all(isinstance(p.condition.get(c), (int, float)) for p in self.points):
                return c
        raise CampaignError(f"{self.source}: no numeric condition column to run trends over")


def load_manifest(path: str | Path, *, method: str | None = None, refine: bool | None = None,
                  profile: str | None = None, condition: str | None = None) -> Campaign:
    """Read a TOML manifest or a CSV test matrix; keyword arguments override the manifest's
    campaign-wide settings (the command line's ``--method``, ``--refine``, ``--profile``)."""
    path = Path(path)
    text = read_text(path, CampaignError, "manifest")
    if path.suffix.lower() == ".csv":
        head, rows = {}, _csv_rows(text, str(path))
    else:
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise CampaignError(f"{path}: not valid TOML ({exc})") from None
        unknown = set(data) - {"campaign", "options", "point"}
        if unknown:
            raise CampaignError(f"{path}: unknown table(s) {', '.join(sorted(unknown))} "
                                f"(expected [campaign], [options], [[point]])")
        head = _table(data.get("campaign", {}), "[campaign]", path)
        bad = set(head) - CAMPAIGN_KEYS
        if bad:
            raise CampaignError(f"{path}: [campaign] has unknown key(s) {', '.join(sorted(bad))}")
        if "matrix" in head:
            matrix = path.parent / _text(head["matrix"], "[campaign] matrix", path)
            rows = _csv_rows(read_text(matrix, CampaignError, "test matrix"), str(matrix))
        else:
            rows = data.get("point", [])
            if not isinstance(rows, list):
                raise CampaignError(f"{path}: 'point' must be [[point]] tables")
        options = _table(data.get("options", {}), "[options]", path)
        for k, v in options.items():
            if not isinstance(v, (bool, int, float, str)):
                raise CampaignError(f"{path}: [options] {k} must be a number, string or boolean")
        head = {**head, "options": options}
    method = method or head.get("method", "ml")
    if method not in METHOD_NAMES:
        raise CampaignError(f"{path}: unknown method '{method}' (registered: {', '.join(METHOD_NAMES)})")
    refine = bool(head.get("refine", False)) if refine is None else refine
    points = tuple(_point(i, row, head, profile, path) for i, row in enumerate(rows))
    if not points:
        raise CampaignError(f"{path}: no test points")
    names = [p.name for p in points]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise CampaignError(f"{path}: duplicate point name(s) {', '.join(dup)}")
    prior = head.get("prior")
    if prior is not None and prior not in PRIORS:
        raise CampaignError(f"{path}: [campaign] prior = {prior!r}: expected one of {', '.join(map(repr, PRIORS))}")
    camp = Campaign(str(head.get("name", path.stem)), points, method, refine,
                    condition or head.get("condition"), head.get("options", {}), str(path), prior)
    if camp.condition and camp.condition not in camp.condition_columns:
        raise CampaignError(f"{path}: condition '{camp.condition}' is no column of the points "
                            f"({', '.join(camp.condition_columns) or 'none'})")
    return camp


def _point(i: int, row: dict, head: dict, profile: str | None, path: Path) -> Point:
    where = f"{path}: point {i + 1}"
    row = _table(row, where, path)
    name = str(row.get("name") or row.get("point") or f"point{i + 1:03d}")
    where = f"{path}: point {name}"
    cond, trim = {}, {}
    for k, v in row.items():
        if k in POINT_KEYS or k == "point":
            continue
        if not isinstance(v, (int, float, str)) or isinstance(v, bool):
            raise CampaignError(f"{where}: condition '{k}' must be a number or text, got {v!r}")
        if isinstance(v, float) and not math.isfinite(v):
            raise CampaignError(f"{where}: '{k}' = {v} is not a finite number")
        if isinstance(v, str) and v.lower().endswith(FILE_SUFFIXES):  # a misspelt key, not a condition
            raise CampaignError(f"{where}: '{k}' = {v!r} names a file but is no point key "
                                f"(keys: {', '.join(sorted(POINT_KEYS))}; other keys are conditions)")
        if k.startswith(TRIM):
            if isinstance(v, str):
                raise CampaignError(f"{where}: trim value '{k}' must be a number, got {v!r}")
            trim[k[len(TRIM):]] = float(v)
        else:
            cond[k] = v
    runs = _patterns(row.get("runs"), f"{where}: runs", path)  # none yet: a campaign to design
    prof = profile or row.get("profile") or head.get("profile")
    if not prof:
        raise CampaignError(f"{where}: no profile (give one per point or in [campaign])")
    cmap = row.get("channel_map") or head.get("channel_map")
    return Point(name, cond, runs, _patterns(row.get("validate"), f"{where}: validate", path),
                 _text(prof, f"{where}: profile", path), cmap and _text(cmap, f"{where}: channel_map", path),
                 trim, str(path.parent))


def _csv_rows(text: str, source: str) -> list[dict]:
    """Rows of a CSV test matrix; numeric cells become numbers, empty cells are left out."""
    reader = csv.DictReader(io.StringIO(text))
    if not reader.fieldnames or not {"point", "name"} & set(reader.fieldnames):
        raise CampaignError(f"{source}: a test matrix needs a header row with a 'point' column")
    rows = []
    for row in reader:
        out = {}
        for k, v in row.items():
            if k is None or v is None:
                raise CampaignError(f"{source}: row {reader.line_num}: more cells than header columns")
            v = v.strip()
            if v:
                out[k.strip()] = _number(v)
        rows.append(out)
    return rows


def _number(text: str):
    try:
        return int(text)
    except ValueError:
        pass
    try:
        return float(text)
    except ValueError:
        return text


def _patterns(value, where: str, path: Path) -> tuple[str, ...]:
    if value is None:
        return ()
    if isinstance(value, str):
        value = [v.strip() for v in value.split(";") if v.strip()]
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise CampaignError(f"{where} must be a file pattern or a list of them")
    return tuple(value)


def _table(value, where: str, path: Path) -> dict:
    if not isinstance(value, dict):
        raise CampaignError(f"{path}: {where} must be a table")
    return value


def _text(value, where: str, path: Path) -> str:
    if not isinstance(value, str):
        raise CampaignError(f"{where} must be text, got {value!r}")
    return value

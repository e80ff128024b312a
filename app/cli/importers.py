"""Importers that load foreign data through the REST API, like any other client.

``fleethealth import-cmapss PATH`` reads a NASA C-MAPSS file, ``train_FD001.txt`` to
``test_FD004.txt`` (columns in ``shared/data/cmapss/SOURCE.md``), and names everything after the
file (``CmapssSet``): each unit becomes an engine (ESN ``FD002-test-007``) installed on its own
tail (``CM-FD002-test-007``, position 1) and of the set's engine type (``CMAPSS-FD002``: train
and test units of one set are the same simulated engine, so a design made on one trends the
other), each cycle one take-off snapshot, one day apart from a fixed start (UTC). Two sets
imported into one server never share an engine, a tail or a type. The three settings are the
operating condition (altitude in kft -> alt_ft, Mach, TRA -> power_pct; FD001 and FD003 fly
sea level static at TRA 100, FD002 and FD004 six conditions up to 42 kft); the sensors that
exist in the built-in engine keep their C-MAPSS units, declared in the CSV header (T24, T30,
T50 degR; P15, P30 psia; Nf, Nc rpm). C-MAPSS's Ps30 (~47.5 "psia") and phi (fuel flow /
Ps30) are not on the scale of P30 and are left out, as are T2/P2 (the inlet follows from the
operating condition) and the derived columns (epr, NRf, NRc, BPR, farB, htBleed, demands, bleeds
W31/W32).

The data is mapped to the built-in engine, not to a type identified from the data: C-MAPSS
carries no health parameters and no linear model, and its sensors are the built-in engine's
(same stations, same units), so the built-in engine's models, scheduled on each record's
operating condition, are the ones its deterioration is read against. Unless told not to, the
import leaves the set's engine type ready to trend and alert: the built-in engine linearised at
sea level static, TRA 100 (a condition of every set: ``POST /api/v1/engine-models/builtin``;
the estimator schedules its trims and gains on each record's condition), a design on it (SVD,
``FD001_TUNERS`` tuners, the C-MAPSS sensors above, the ten turbomachinery health parameters:
``fd001_design_spec``) and that design activated, so the estimation job that follows runs the
filter, the shift detector and the wear detector on every unit. An engine type that already has
an active design keeps it.
"""

from __future__ import annotations

import hashlib
import io
import re
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Annotated, Any

import httpx
import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import typer

CMAPSS_COLUMNS = (
    "unit", "cycle", "setting1", "setting2", "setting3",
    "T2", "T24", "T30", "T50", "P2", "P15", "P30", "Nf", "Nc", "epr", "Ps30", "phi",
    "NRf", "NRc", "BPR", "farB", "htBleed", "Nf_dmd", "PCNfR_dmd", "W31", "W32",
)  # fmt: skip
# C-MAPSS column -> upload column with its unit (the built-in engine's names).
CMAPSS_SENSORS = {
    "T24": "T24[degR]",
    "T30": "T30[degR]",
    "T50": "T50[degR]",
    "P15": "P15[psia]",
    "P30": "P30[psia]",
    "Nf": "Nf[rpm]",
    "Nc": "Nc[rpm]",
}
CMAPSS_START = datetime(2020, 1, 1, tzinfo=UTC)
CMAPSS_DATASETS = ("FD001", "FD002", "FD003", "FD004")
CMAPSS_SPLITS = ("train", "test")
_FILE_NAME = re.compile(r"^(train|test)_(FD00[1-4])\.txt$", re.IGNORECASE)
# Sea level static, TRA 100 (power 100 %): FD001's one condition and one of FD002's six; the
# design model of every set is linearised there.
FD001_CONDITION = {"alt_ft": 0.0, "mach": 0.0, "power_pct": 100.0, "dtamb_k": 0.0}
FD001_TUNERS = 7
_RANKINE = 1.8
_T_SL = 288.15
_LAPSE = 0.0065  # K/m, ISA troposphere
_FT = 0.3048


class CmapssImportError(RuntimeError):
    """The server refused a step of the import; the message carries its answer."""


@dataclass(frozen=True)
class CmapssSet:
    """Which C-MAPSS file is imported (``FD002``, ``test``): the names of its engines, tails,
    engine type, model and design."""

    dataset: str
    split: str

    def __post_init__(self) -> None:
        if self.dataset not in CMAPSS_DATASETS or self.split not in CMAPSS_SPLITS:
            raise CmapssImportError(
                f"unknown C-MAPSS set {self.dataset!r} {self.split!r}: "
                f"one of {', '.join(CMAPSS_DATASETS)}, train or test")

    @classmethod
    def of_file(cls, path: Path) -> CmapssSet:
        """The set named by NASA's file name (``train_FD001.txt`` ... ``test_FD004.txt``)."""
        match = _FILE_NAME.match(path.name)
        if match is None:
            raise CmapssImportError(
                f"{path.name}: not a C-MAPSS file name (train_FD001.txt ... test_FD004.txt); "
                "name the set with --dataset and --split")
        return cls(match.group(2).upper(), match.group(1).lower())

    @property
    def label(self) -> str:
        return f"{self.dataset}-{self.split}"

    @property
    def engine_type(self) -> str:
        return f"CMAPSS-{self.dataset}"

    @property
    def model_name(self) -> str:
        return f"{self.dataset} sea level static"

    @property
    def design_name(self) -> str:
        return f"{self.dataset} SVD {FD001_TUNERS} tuners"

    def esn(self, unit: int) -> str:
        return f"{self.label}-{unit:03d}"

    def tail(self, unit: int) -> str:
        return f"CM-{self.label}-{unit:03d}"


FD001_TRAIN = CmapssSet("FD001", "train")


@dataclass(frozen=True)
class ImportSummary:
    units: int
    snapshots: int
    stored: int
    duplicates: int
    uploads: list[int]
    design_id: int | None = None  # the engine type's active design (None: not asked for)
    design_created: bool = False


def fd001_design_spec(health_names: list[str], tuners: int = FD001_TUNERS) -> dict[str, Any]:
    """The design an FD001 user starts with: SVD tuners over the ten turbomachinery health
    parameters (the built-in model's first ten: fan, LPC, HPC, HPT, LPT efficiency and flow),
    the C-MAPSS sensors the built-in engine has."""
    return {
        "format": "fleethealth.design-spec/1", "method": "svd", "tuners": tuners,
        "sensors": list(CMAPSS_SENSORS), "health": list(health_names[:10]),
        "noise": {"Q": 1e-4, "Qh": 1e-4, "Ph": 4.0},
    }


def ensure_design(
    client: httpx.Client, engine_type_id: int, cmapss: CmapssSet = FD001_TRAIN
) -> tuple[int, bool]:
    """The engine type's active design, or a new one made and activated through the API
    (the built-in engine at ``FD001_CONDITION``, ``fd001_design_spec``): (design id, created).
    A design that fails is an error naming the server's reason."""
    active = _check(client.get(f"/api/v1/engine-types/{engine_type_id}/active-design"),
                    "read the active design")
    if active:
        return int(active["id"]), False
    model = _check(
        client.post("/api/v1/engine-models/builtin",
                    json={"engine_type_id": engine_type_id, "name": cmapss.model_name,
                          **FD001_CONDITION}),
        "linearise the built-in engine at sea level static, TRA 100",
    )
    design = _check(
        client.post("/api/v1/designs",
                    json={"engine_model_id": model["id"], "name": cmapss.design_name,
                          "spec": fd001_design_spec(model["health_names"])}),
        f"create the {cmapss.dataset} design",
    )
    if design["status"] != "ready":
        raise CmapssImportError(f"the {cmapss.dataset} design {design['id']} is "
                                f"{design['status']}: {design.get('failure')}")
    _check(client.post(f"/api/v1/designs/{design['id']}/activate"),
           f"activate the {cmapss.dataset} design")
    return int(design["id"]), True


def read_cmapss(path: Path) -> np.ndarray:
    """The file as a [rows, 26] float array in ``CMAPSS_COLUMNS`` order."""
    data = np.loadtxt(path, dtype=float, ndmin=2)
    if data.shape[1] != len(CMAPSS_COLUMNS):
        raise CmapssImportError(
            f"{path}: expected {len(CMAPSS_COLUMNS)} columns of C-MAPSS data, got {data.shape[1]}"
        )
    return data


def select_units(data: np.ndarray, units: int | None) -> tuple[np.ndarray, list[int]]:
    """The rows of the first ``units`` unit numbers (all: None) and those unit numbers."""
    unit_ids = sorted({int(u) for u in data[:, 0]})
    if units is not None:
        unit_ids = unit_ids[:units]
        data = data[np.isin(data[:, 0].astype(int), unit_ids)]
    return data, unit_ids


def cmapss_snapshots(
    data: np.ndarray, start: datetime = CMAPSS_START, cmapss: CmapssSet = FD001_TRAIN
) -> pa.Table:
    """Rows of the C-MAPSS array as upload columns (docs/upload-format.md), sensors in
    C-MAPSS units, engines and tails named after ``cmapss``."""
    col = {name: data[:, i] for i, name in enumerate(CMAPSS_COLUMNS)}
    units = col["unit"].astype(np.int64)
    cycles = col["cycle"].astype(np.int64)
    alt_ft = col["setting1"] * 1000.0
    # Settings scatter around their condition (FD001's Mach by +-0.0009); a negative Mach is
    # noise, not flight.
    mach = np.clip(col["setting2"], 0.0, None)
    # dTamb from the inlet: T2 is total temperature, T_amb = T2 / (1 + 0.2 M^2), against ISA.
    t_amb = col["T2"] / _RANKINE / (1.0 + 0.2 * mach**2)
    t_isa = _T_SL - _LAPSE * np.minimum(alt_ft * _FT, 11000.0)
    times = np.datetime64(start.replace(tzinfo=None), "us") + (cycles - 1) * np.timedelta64(1, "D")
    columns: dict[str, Any] = {
        "recorded_at": pa.array(times, pa.timestamp("us", tz="UTC")),
        "tail": pa.array([cmapss.tail(u) for u in units]),
        "position": pa.array(np.ones(len(units), dtype=np.int64)),
        "phase": pa.array(["takeoff"] * len(units)),
        "flight_id": pa.array(
            [f"{cmapss.esn(u)}-C{c:04d}" for u, c in zip(units, cycles, strict=True)]
        ),
        "alt_ft": alt_ft,
        "mach": mach,
        "dtamb_k": np.round(t_amb - t_isa, 6),
        "power_pct": col["setting3"],
    }
    for source, target in CMAPSS_SENSORS.items():
        columns[target] = col[source]
    return pa.table(columns)


def _check(response: httpx.Response, what: str) -> dict[str, Any]:
    if response.status_code >= 400:
        raise CmapssImportError(f"{what}: HTTP {response.status_code}: {response.text[:500]}")
    result: dict[str, Any] = response.json()
    return result


def _find_one(client: httpx.Client, path: str, **params: Any) -> dict[str, Any] | None:
    page = _check(client.get(path, params=params), f"GET {path}")
    items = page["items"]
    return items[0] if items else None


def ensure_engine_type(client: httpx.Client, cmapss: CmapssSet = FD001_TRAIN) -> int:
    name = cmapss.engine_type
    offset = 0
    while True:
        page = _check(
            client.get("/api/v1/engine-types", params={"limit": 100, "offset": offset}),
            "list engine types",
        )
        for item in page["items"]:
            if item["name"] == name:
                return int(item["id"])
        offset += len(page["items"])
        if not page["items"] or offset >= page["total"]:
            break
    created = _check(
        client.post(
            "/api/v1/engine-types",
            json={"name": name,
                  "description": f"NASA C-MAPSS {cmapss.dataset} engines (imported)"},
        ),
        "create engine type",
    )
    return int(created["id"])


def ensure_unit(
    client: httpx.Client, unit: int, engine_type_id: int, start: datetime,
    cmapss: CmapssSet = FD001_TRAIN,
) -> int:
    """Aircraft, engine and installation of one C-MAPSS unit (created once); the engine id."""
    tail, esn = cmapss.tail(unit), cmapss.esn(unit)
    aircraft = _find_one(client, "/api/v1/aircraft", tail=tail) or _check(
        client.post("/api/v1/aircraft", json={"tail": tail, "engine_positions": 1}),
        f"create aircraft {tail}",
    )
    engine = _find_one(client, "/api/v1/engines", esn=esn) or _check(
        client.post("/api/v1/engines", json={"esn": esn, "engine_type_id": engine_type_id}),
        f"create engine {esn}",
    )
    installed = _find_one(client, f"/api/v1/engines/{engine['id']}/installations")
    if installed is None:
        _check(
            client.post(
                "/api/v1/installations",
                json={
                    "engine_id": engine["id"],
                    "aircraft_id": aircraft["id"],
                    "position": 1,
                    "installed_at": (start - timedelta(days=1)).isoformat(),
                },
            ),
            f"install {esn} on {tail}",
        )
    return int(engine["id"])


def import_cmapss(
    path: Path,
    client: httpx.Client,
    *,
    units: int | None = None,
    batch_rows: int = 5000,
    start: datetime = CMAPSS_START,
    progress: Callable[[int], None] | None = None,
    design: bool = True,
    cmapss: CmapssSet | None = None,
) -> ImportSummary:
    """Create the fleet and upload the snapshots of the first ``units`` units (all: None),
    named after ``cmapss`` (None: the set the file name says).

    Each batch carries an Idempotency-Key derived from the file and the batch, so running
    the import again stores nothing new. ``progress`` is called with the rows of each batch.
    With ``design`` the engine type gets a ready, active design first (``ensure_design``),
    so the uploads' estimation trends and alerts at once.
    """
    cmapss = cmapss or CmapssSet.of_file(path)
    data, unit_ids = select_units(read_cmapss(path), units)
    engine_type_id = ensure_engine_type(client, cmapss)
    design_id, design_created = (ensure_design(client, engine_type_id, cmapss) if design
                                 else (None, False))
    for unit in unit_ids:
        ensure_unit(client, unit, engine_type_id, start, cmapss)
    table = cmapss_snapshots(data, start, cmapss)
    file_digest = hashlib.sha256(path.read_bytes()).hexdigest()[:16]
    stored = duplicates = 0
    uploads: list[int] = []
    for index, offset in enumerate(range(0, table.num_rows, batch_rows)):
        batch = table.slice(offset, batch_rows)
        sink = io.BytesIO()
        pacsv.write_csv(batch, sink)
        key = (f"cmapss:{cmapss.label}:{file_digest}:{start.date()}:{len(unit_ids)}:"
               f"{batch_rows}:{index}")
        result = _check(
            client.post(
                "/api/v1/snapshots/file",
                params={"source": "cli", "filename": path.name},
                content=sink.getvalue(),
                headers={"Content-Type": "text/csv", "Idempotency-Key": key},
            ),
            f"upload batch {index + 1}",
        )
        uploads.append(int(result["id"]))
        if result["replayed"]:  # this batch was uploaded before: nothing new stored now
            duplicates += int(result["rows_received"])
        else:
            stored += int(result["rows_stored"])
            duplicates += int(result["rows_duplicate"])
        if progress is not None:
            progress(batch.num_rows)
    return ImportSummary(len(unit_ids), table.num_rows, stored, duplicates, uploads,
                         design_id, design_created)


def import_cmapss_command(
    path: Annotated[
        Path, typer.Argument(exists=True, dir_okay=False,
                             help="C-MAPSS train_FD001.txt ... test_FD004.txt")
    ],
    url: str = typer.Option("http://127.0.0.1:8000", help="fleethealth server URL."),
    api_key: str = typer.Option(..., envvar="FLEETHEALTH_API_KEY", help="An analyst key."),
    units: int | None = typer.Option(None, min=1, help="Import only the first N units."),
    batch_rows: int = typer.Option(5000, min=1, help="Snapshots per upload request."),
    design: bool = typer.Option(
        True, help="Give the engine type a ready, active design at sea level static, TRA 100 "
        "(unless it has one)."),
    dataset: str | None = typer.Option(
        None, help="FD001 ... FD004, for a file not under NASA's name (with --split)."),
    split: str | None = typer.Option(None, help="train or test (with --dataset)."),
) -> None:
    """Upload a NASA C-MAPSS file (FD001-FD004, train or test) through the REST API: one
    engine and tail per unit, named after the file, and an engine type per set."""
    try:
        if (dataset is None) != (split is None):
            raise CmapssImportError("--dataset and --split go together")
        cmapss = (CmapssSet(dataset.upper(), split.lower()) if dataset and split
                  else CmapssSet.of_file(path))
    except CmapssImportError as exc:
        raise typer.BadParameter(str(exc)) from exc
    total = select_units(read_cmapss(path), units)[0].shape[0]
    with httpx.Client(base_url=url, headers={"X-API-Key": api_key}, timeout=300) as client:
        with typer.progressbar(length=total, label="uploading snapshots") as bar:
            summary = import_cmapss(
                path, client, units=units, batch_rows=batch_rows, progress=bar.update,
                design=design, cmapss=cmapss,
            )
    typer.echo(
        f"{summary.units} engines, {summary.snapshots} snapshots: {summary.stored} stored, "
        f"{summary.duplicates} already there ({len(summary.uploads)} uploads)"
    )
    if summary.design_id is not None:
        typer.echo(f"design {summary.design_id} "
                   f"{'created and activated' if summary.design_created else 'already active'}"
                   f" for {cmapss.engine_type}: estimation runs in the server's jobs")


def register(app: typer.Typer) -> None:
    app.command("import-cmapss")(import_cmapss_command)

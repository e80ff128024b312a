"""Parsing and validation of upload bodies: formats agree, units convert, bad input is named."""

from __future__ import annotations

import io
import json
from datetime import UTC, datetime, timedelta
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq
import pytest

from app.services.uploads.parse import (
    MAX_ERRORS,
    UploadRejected,
    parse_body,
    parse_csv,
    parse_json,
    parse_parquet,
    split_unit,
)

T0 = datetime(2026, 3, 1, 8, 0, tzinfo=UTC)


def records(n: int = 6, seed: int = 1) -> list[dict[str, Any]]:
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(n):
        rows.append(
            {
                "recorded_at": (T0 + timedelta(hours=i)).isoformat().replace("+00:00", "Z"),
                "tail": f"N{100 + i % 2}",
                "position": 1 + i % 2,
                "phase": ("takeoff", "climb", "cruise")[i % 3],
                "flight_id": f"F{i // 2}",
                "alt_ft": float(rng.uniform(0, 39000)),
                "mach": float(rng.uniform(0, 0.85)),
                "dtamb_k": float(rng.normal(0, 5)),
                "power_pct": float(rng.uniform(60, 100)),
                "T30": float(rng.uniform(1300, 1600)),
                "P30": float(rng.uniform(300, 560)),
                "Nf": float(rng.uniform(2000, 2400)),
                "Wf": None if i == 2 else float(rng.uniform(0.5, 2.0)),
            }
        )
    return rows


def to_csv(rows: list[dict[str, Any]], rename: dict[str, str] | None = None) -> bytes:
    rename = rename or {}
    names = list(rows[0])
    lines = [",".join(rename.get(n, n) for n in names)]
    for row in rows:
        lines.append(",".join("" if row[n] is None else repr(row[n]).strip("'") for n in names))
    return ("\n".join(lines) + "\n").encode()


def to_parquet(table: pa.Table) -> bytes:
    sink = io.BytesIO()
    pq.write_table(table, sink)
    return sink.getvalue()


def rejected(call: Any, *args: Any, **kwargs: Any) -> list[dict[str, Any]]:
    with pytest.raises(UploadRejected) as info:
        call(*args, **kwargs)
    assert info.value.status_code == 422
    return info.value.details


def test_split_unit() -> None:
    assert split_unit("T30[degC]") == ("T30", "degC")
    assert split_unit(" P30 [kPa] ") == ("P30", "kPa")
    assert split_unit("tail") == ("tail", None)


def test_csv_json_and_parquet_of_the_same_rows_give_the_same_table() -> None:
    rows = records()
    from_json = parse_json(json.dumps({"snapshots": rows}).encode()).table
    from_csv = parse_csv(to_csv(rows)).table
    arrow = pa.Table.from_pylist(rows)
    from_parquet = parse_parquet(to_parquet(arrow)).table
    assert from_csv.equals(from_json.select(from_csv.column_names))
    assert from_parquet.equals(from_json.select(from_parquet.column_names))
    got = from_json.to_pylist()
    assert [r["recorded_at"] for r in got] == [T0 + timedelta(hours=i) for i in range(len(rows))]
    assert got[2]["Wf"] is None and got[3]["Wf"] == rows[3]["Wf"]


def test_parquet_with_tz_aware_timestamps_and_float_positions() -> None:
    rows = records()
    table = pa.Table.from_pylist(rows)
    times = pa.array(
        [T0 + timedelta(hours=i) for i in range(len(rows))], pa.timestamp("ms", tz="Europe/Paris")
    )
    table = table.set_column(0, "recorded_at", times)
    table = table.set_column(2, "position", pa.array([float(r["position"]) for r in rows]))
    parsed = parse_parquet(to_parquet(table)).table
    assert parsed["recorded_at"].to_pylist() == [T0 + timedelta(hours=i) for i in range(len(rows))]
    assert parsed["position"].to_pylist() == [r["position"] for r in rows]


def test_declared_units_convert_to_stored_units() -> None:
    rows = records()
    celsius = [r["T30"] / 1.8 - 273.15 for r in rows]
    kpa = [r["P30"] * 6.894757293168 for r in rows]
    for row, c, k in zip(rows, celsius, kpa, strict=True):
        row["T30"], row["P30"] = c, k
    parsed = parse_csv(to_csv(rows, {"T30": "T30[degC]", "P30": "P30[kPa]"})).table
    expected = records()
    np.testing.assert_allclose(parsed["T30"].to_numpy(), [r["T30"] for r in expected])
    np.testing.assert_allclose(parsed["P30"].to_numpy(), [r["P30"] for r in expected])
    # The JSON way of declaring the same units.
    body = {"units": {"T30": "degC", "P30": "kPa"}, "snapshots": rows}
    from_json = parse_json(json.dumps(body).encode()).table
    np.testing.assert_allclose(from_json["T30"].to_numpy(), parsed["T30"].to_numpy())


def test_percent_speed_is_percent_of_the_design_speed() -> None:
    rows = records()
    for row in rows:
        row["Nf"] = 100.0 * row["Nf"] / 2388.06
    parsed = parse_csv(to_csv(rows, {"Nf": "Nf[%]"})).table
    np.testing.assert_allclose(parsed["Nf"].to_numpy(), [r["Nf"] for r in records()])


def test_column_mapping_renames_and_drops() -> None:
    rows = records()
    for row in rows:
        row["HPC_T"] = row.pop("T30")
        row["junk"] = 1.0
    body = to_csv(rows)
    assert any(e["column"] == "HPC_T" for e in rejected(parse_csv, body))
    parsed = parse_csv(body, mapping={"HPC_T": "T30[degR]", "junk": None}).table
    np.testing.assert_allclose(parsed["T30"].to_numpy(), [r["T30"] for r in records()])
    assert "junk" not in parsed.column_names


@pytest.mark.parametrize("token", ["nan", "inf", "-inf", "NaN"])
def test_csv_refuses_nan_and_infinity_naming_row_and_column(token: str) -> None:
    rows = records()
    body = to_csv(rows).decode().splitlines()
    cells = body[3].split(",")
    cells[9] = token  # T30 of data row 3
    body[3] = ",".join(cells)
    details = rejected(parse_csv, ("\n".join(body) + "\n").encode())
    assert details == [
        {"row": 3, "column": "T30", "reason": details[0]["reason"]},
    ]
    assert "not a number the API accepts" in details[0]["reason"]


def test_json_refuses_nan_and_infinity_literals() -> None:
    text = json.dumps({"snapshots": records()})
    text = text.replace('"Wf": null', '"Wf": NaN', 1)
    details = rejected(parse_json, text.encode())
    assert [(d["row"], d["column"]) for d in details] == [(3, "Wf")]


def test_parquet_refuses_nan() -> None:
    rows = records()
    rows[4]["P30"] = float("inf")
    details = rejected(parse_parquet, to_parquet(pa.Table.from_pylist(rows)))
    assert [(d["row"], d["column"]) for d in details] == [(5, "P30")]


def test_naive_timestamps_are_refused() -> None:
    rows = records()
    rows[1]["recorded_at"] = "2026-03-01T09:00:00"
    details = rejected(parse_csv, to_csv(rows))
    assert [(d["row"], d["column"]) for d in details] == [(2, "recorded_at")]
    assert "no time zone" in details[0]["reason"]
    table = pa.Table.from_pylist(records()).set_column(
        0, "recorded_at", pa.array([datetime(2026, 3, 1)] * 6, pa.timestamp("us"))
    )
    details = rejected(parse_parquet, to_parquet(table))
    assert "no time zone" in details[0]["reason"]


def test_unknown_column_and_unknown_unit_reject_the_upload() -> None:
    rows = records()
    for row in rows:
        row["EGT"] = 900.0
    details = rejected(parse_csv, to_csv(rows))
    assert details == [{"row": None, "column": "EGT", "reason": "unknown column 'EGT'"}]
    details = rejected(parse_csv, to_csv(records(), {"T30": "T30[kelvins]"}))
    assert (
        details[0]["column"] == "T30[kelvins]" and "unknown unit 'kelvins'" in details[0]["reason"]
    )
    details = rejected(
        parse_json, json.dumps({"units": {"T30": "furlong"}, "snapshots": records()}).encode()
    )
    assert "unknown unit 'furlong'" in details[0]["reason"]


def test_wrong_types_are_named_per_cell() -> None:
    rows = records()
    rows[0]["Nf"] = "fast"
    rows[2]["position"] = "left"
    rows[3]["phase"] = "taxi"
    details = rejected(parse_csv, to_csv(rows))
    assert [(d["row"], d["column"]) for d in details] == [(1, "Nf"), (3, "position"), (4, "phase")]
    rows = records()
    rows[1]["Nf"] = "fast"
    rows[2]["alt_ft"] = True
    rows[4]["position"] = 1.5
    details = rejected(parse_json, json.dumps({"snapshots": rows}).encode())
    assert [(d["row"], d["column"]) for d in details] == [(2, "Nf"), (3, "alt_ft"), (5, "position")]


def test_out_of_range_operating_condition_and_missing_required_values() -> None:
    rows = records()
    rows[0]["mach"] = 1.5
    rows[1]["power_pct"] = None
    rows[2]["tail"] = ""
    details = rejected(parse_csv, to_csv(rows))
    assert [(d["row"], d["column"]) for d in details] == [
        (1, "mach"),
        (2, "power_pct"),
        (3, "tail"),
    ]
    rows = records()
    for row in rows:
        del row["dtamb_k"]
    details = rejected(parse_csv, to_csv(rows))
    assert details == [
        {"row": None, "column": "dtamb_k", "reason": "required column 'dtamb_k' is missing"}
    ]


def test_duplicate_rows_inside_one_upload() -> None:
    rows = records()
    rows.append(dict(rows[1]))
    details = rejected(parse_csv, to_csv(rows))
    assert details == [
        {
            "row": len(rows),
            "column": "recorded_at",
            "reason": "duplicate of row 2 (same tail, position and recorded_at)",
        }
    ]


def test_malformed_truncated_and_empty_bodies() -> None:
    good = to_csv(records())
    bad_csv = good.decode().splitlines()
    bad_csv[2] = bad_csv[2] + ",1,2"
    assert "malformed CSV" in rejected(parse_csv, ("\n".join(bad_csv) + "\n").encode())[0]["reason"]
    parquet = to_parquet(pa.Table.from_pylist(records()))
    assert "malformed Parquet" in rejected(parse_parquet, parquet[: len(parquet) // 2])[0]["reason"]
    assert "malformed Parquet" in rejected(parse_parquet, b"PAR1 not really")[0]["reason"]
    text = json.dumps({"snapshots": records()})
    assert "malformed JSON" in rejected(parse_json, text[:-20].encode())[0]["reason"]
    for fmt in ("csv", "json", "parquet"):
        assert "empty" in rejected(parse_body, b"", fmt)[0]["reason"]
    header_only = good.split(b"\n", 1)[0] + b"\n"
    assert "no rows" in rejected(parse_csv, header_only)[0]["reason"]


def test_errors_stop_at_the_cap() -> None:
    rows = records(3 * MAX_ERRORS)
    for row in rows:
        row["Nf"] = "x"
    with pytest.raises(UploadRejected) as info:
        parse_csv(to_csv(rows))
    assert len(info.value.details) == MAX_ERRORS and info.value.truncated
    assert [d["row"] for d in info.value.details] == list(range(1, MAX_ERRORS + 1))


def test_a_large_csv_parses_column_by_column() -> None:
    n = 20_000
    rng = np.random.default_rng(7)
    times = pa.array(
        np.datetime64("2026-01-01T00:00:00", "us") + np.arange(n) * np.timedelta64(60, "s"),
        pa.timestamp("us", tz="UTC"),
    )
    table = pa.table(
        {
            "recorded_at": times,
            "tail": pa.array([f"N{i % 40}" for i in range(n)]),
            "position": pa.array(1 + (np.arange(n) // 40) % 2),
            "phase": pa.array(["cruise"] * n),
            "alt_ft": rng.uniform(0, 40000, n),
            "mach": rng.uniform(0, 0.85, n),
            "dtamb_k": rng.normal(0, 5, n),
            "power_pct": rng.uniform(50, 100, n),
            "T50": rng.uniform(1300, 1500, n),
        }
    )
    sink = io.BytesIO()
    pacsv.write_csv(table, sink)
    parsed = parse_csv(sink.getvalue()).table
    assert parsed.num_rows == n
    np.testing.assert_array_equal(parsed["T50"].to_numpy(), table["T50"].to_numpy())
    assert parsed["recorded_at"].equals(table["recorded_at"])


def test_stream_time_axis_must_be_fixed_rate() -> None:
    t = np.arange(50) * 0.05
    samples = pa.table(
        {
            "time_s": t,
            "alt_ft": np.full(50, 30000.0),
            "mach": np.full(50, 0.8),
            "dtamb_k": np.zeros(50),
            "power_pct": np.full(50, 90.0),
            "T30[degC]": np.full(50, 500.0),
        }
    )
    parsed = parse_parquet(to_parquet(samples), kind="stream").table
    np.testing.assert_allclose(parsed["T30"].to_numpy(), (500.0 + 273.15) * 1.8)
    t_bad = t.copy()
    t_bad[10] = t_bad[9]
    details = rejected(
        parse_parquet, to_parquet(samples.set_column(0, "time_s", pa.array(t_bad))), kind="stream"
    )
    assert (details[0]["row"], details[0]["column"]) == (11, "time_s")


def test_stored_signals_are_the_built_in_engines_sensors_in_its_units() -> None:
    from app.signals import ACTUATORS, SENSORS
    from estimation.engine.sensors import SENSOR_NAMES, SENSOR_UNITS

    stored = {s.name: s.unit for s in SENSORS + ACTUATORS}
    engine = dict(zip(SENSOR_NAMES, SENSOR_UNITS, strict=True))
    assert {name: stored[name] for name in engine} == engine
    assert set(stored) - set(engine) == {"VSV", "VBV"}  # actuator positions, not sensors


def test_by_type_keeps_any_signal_as_sent_with_its_declared_unit() -> None:
    """Snapshots parsed by type: names and units are decided per row's engine type later, so
    any signal column is read as numbers, unconverted, with its declared unit and file column;
    the operating condition and phase are no longer required here."""
    body = (b"recorded_at,tail,position,EGT[degC],N1,T30[degC]\n"
            b"2026-03-01T00:00:00Z,N1,1,505.5,98.5,600\n"
            b"2026-03-01T00:10:00Z,N1,1,,99,\n")
    parsed = parse_body(body, "csv", by_type=True)
    assert parsed.table["EGT"].to_pylist() == [505.5, None]
    assert parsed.table["T30"].to_pylist() == [600.0, None]  # not converted yet
    assert dict(parsed.units) == {"EGT": "degC", "N1": None, "T30": "degC"}
    assert dict(parsed.sources) == {"EGT": "EGT[degC]", "N1": "N1", "T30": "T30[degC]"}
    # Keys stay keys: a unit on one, or a missing one, is refused here.
    errors = rejected(parse_body, b"recorded_at,tail,position[m],EGT\n"
                      b"2026-03-01T00:00:00Z,N1,1,1\n", "csv", by_type=True)
    assert errors[0]["reason"] == "column 'position' takes no unit (got 'm')"
    errors = rejected(parse_body, b"recorded_at,position,EGT\n2026-03-01T00:00:00Z,1,1\n",
                      "csv", by_type=True)
    assert errors == [
        {"row": None, "column": "tail", "reason": "required column 'tail' is missing"}]
    # Text in a signal column is still refused by row.
    errors = rejected(parse_body, b"recorded_at,tail,position,EGT\n"
                      b"2026-03-01T00:00:00Z,N1,1,hot\n", "csv", by_type=True)
    assert errors[0]["row"] == 1 and errors[0]["column"] == "EGT"

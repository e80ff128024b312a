"""``fleethealth simulate``: files in the upload formats that load back and match the simulator."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow.csv as pacsv
import pyarrow.parquet as pq
import pytest
import typer
from typer.testing import CliRunner

from app.cli.simulate import register
from app.services.demo import simulation_files
from app.services.uploads.parse import parse_body
from estimation.engine.fleet import FleetConfig, fleet_snapshots, plan_fleet, stream_flights
from estimation.engine.sensors import SENSOR_NAMES


def _app() -> typer.Typer:
    app = typer.Typer()

    @app.callback()
    def main() -> None:
        """fleethealth (test)."""

    register(app)
    return app


def _run(*args: str) -> None:
    result = CliRunner().invoke(_app(), ["simulate", *args])
    assert result.exit_code == 0, result.output + repr(result.exception)


@pytest.fixture(scope="module")
def snapshot_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("snap")
    _run("--aircraft", "3", "--flights", "4", "--mode", "snapshot", "--seed", "11",
         "--out", str(out))
    return out


def _expected_snapshots(seed: int, aircraft: int, flights: int):
    plan_rng, snap_rng, _ = np.random.default_rng(seed).spawn(3)
    plan = plan_fleet(FleetConfig(n_aircraft=aircraft, n_flights=flights), plan_rng)
    return plan, fleet_snapshots(plan, snap_rng)


def test_snapshot_files_load_back_and_match(snapshot_dir: Path) -> None:
    plan, snaps = _expected_snapshots(11, 3, 4)
    csv_table = pacsv.read_csv(snapshot_dir / "snapshots.csv")
    pq_table = pq.read_table(snapshot_dir / "snapshots.parquet")
    assert csv_table.column_names == pq_table.column_names
    assert csv_table.column_names[:9] == ["recorded_at", "tail", "position", "phase", "flight_id",
                                          "alt_ft", "mach", "dtamb_k", "power_pct"]
    assert "T30[degR]" in csv_table.column_names and "Wf[pps]" in csv_table.column_names
    n = snaps.recorded_at.size
    assert csv_table.num_rows == pq_table.num_rows == n
    first_row = (snapshot_dir / "snapshots.csv").read_text().splitlines()[1]
    text = first_row.split(",")[0].strip('"')
    assert text == simulation_files.iso_utc(snaps.recorded_at[0]) and text.endswith("Z")
    stamps = [t.timestamp() for t in pq_table["recorded_at"].to_pylist()]
    np.testing.assert_array_equal(stamps, np.round(snaps.recorded_at))
    for table in (csv_table, pq_table):
        assert table["tail"].to_pylist() == list(snaps.tail)
        assert table["phase"].to_pylist() == list(snaps.phase)
        np.testing.assert_array_equal(table["position"].to_numpy(), snaps.position)
        np.testing.assert_array_equal(table["alt_ft"].to_numpy(), snaps.alt_ft)
        for k, name in enumerate(SENSOR_NAMES[:-1]):
            unit = table.column_names[[c.split("[")[0] for c in table.column_names].index(name)]
            np.testing.assert_array_equal(table[unit].to_numpy(), snaps.sensors[:, k])
        np.testing.assert_array_equal(table["VSV[%]"].to_numpy(), snaps.actuators[:, 1])
    # The service's own upload parser accepts both files unchanged.
    for fmt in ("csv", "parquet"):
        parsed = parse_body((snapshot_dir / f"snapshots.{fmt}").read_bytes(), fmt)
        assert parsed.num_rows == n
        np.testing.assert_allclose(parsed.table["Nf"].to_numpy(), snaps.sensors[:, 0])


def test_truth_matches_the_plan(snapshot_dir: Path) -> None:
    plan, _ = _expected_snapshots(11, 3, 4)
    doc = json.loads((snapshot_dir / "truth.json").read_text())
    assert doc["esns"] == list(plan.esns) and doc["health_names"][:2] == ["fan_eff", "fan_flow"]
    assert len(doc["health"]) == 3 * 2 * 4
    first = doc["health"][0]
    e = plan.esns.index(first["esn"])
    np.testing.assert_allclose(list(first["health"].values()), plan.health[0, e])
    assert len(doc["installations"]) == len(plan.installations)
    assert len(doc["faults"]) == len(plan.faults) and len(doc["swaps"]) == len(plan.swaps)
    flat = pacsv.read_csv(snapshot_dir / "truth_health.csv")
    assert flat.num_rows == len(doc["health"])
    np.testing.assert_allclose(flat["hpc_eff"].to_numpy(),
                               [r["health"]["hpc_eff"] for r in doc["health"]])


def test_same_seed_same_files(snapshot_dir: Path, tmp_path: Path) -> None:
    _run("--aircraft", "3", "--flights", "4", "--seed", "11", "--out", str(tmp_path),
         "--format", "csv")
    assert (tmp_path / "snapshots.csv").read_bytes() == (
        snapshot_dir / "snapshots.csv").read_bytes()
    assert not (tmp_path / "snapshots.parquet").exists()


def test_stream_files_and_manifest(tmp_path: Path) -> None:
    _run("--aircraft", "1", "--flights", "1", "--mode", "stream", "--seed", "3",
         "--out", str(tmp_path), "--rate-hz", "4", "--stream-seconds", "3")
    manifest = json.loads((tmp_path / "streams" / "manifest.json").read_text())
    assert manifest["units"]["T30"] == "degR" and len(manifest["flights"]) == 2
    plan_rng, _, stream_rng = np.random.default_rng(3).spawn(3)
    plan = plan_fleet(FleetConfig(n_aircraft=1, n_flights=1), plan_rng)
    expected = list(stream_flights(plan, stream_rng, 4.0, 3.0))
    for entry, fl in zip(manifest["flights"], expected, strict=True):
        assert entry["tail"] == fl.tail and entry["position"] == fl.position
        assert entry["started_at"] == simulation_files.iso_utc(fl.started_at)
        assert entry["rate_hz"] == pytest.approx(4.0) and entry["samples"] == 13
        table = pacsv.read_csv(tmp_path / entry["files"][0])
        np.testing.assert_array_equal(table["time_s"].to_numpy(), fl.time_s)
        np.testing.assert_array_equal(table["Nc[rpm]"].to_numpy(), fl.sensors[:, 1])
        np.testing.assert_array_equal(table["power_pct"].to_numpy(), fl.power_pct)
        parquet = pq.read_table(tmp_path / entry["files"][1])
        np.testing.assert_array_equal(parquet["T48[degR]"].to_numpy(), fl.sensors[:, 7])
        parsed = parse_body((tmp_path / entry["files"][0]).read_bytes(), "csv", kind="streams")
        assert parsed.num_rows == 13


def test_bad_mode_is_refused(tmp_path: Path) -> None:
    result = CliRunner().invoke(_app(), ["simulate", "--mode", "movie", "--out", str(tmp_path)])
    assert result.exit_code != 0 and "mode" in result.output

"""Wear detector (estimation/wear.py): closed-form attribution, the vectorised CUSUM against
its recursion, a drift along a known fault alerted and attributed, the false-alarm rate of the
drift CUSUM against Siegmund's approximation (seeded Monte Carlo), the directional bank on
sensor deviations (a drift alerted sooner and named, its family-wise false-alarm rate against
the same approximation) and the FD001 train set (all 100 engines) against the naive signature
CUSUM computed in the same test; the fleet CUSUM's pieces (an engine's drift, the fleet
direction, the matched filter along it, its alerts however the records are split)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from estimation import wear

FD001 = Path(__file__).resolve().parents[3] / "shared" / "data" / "cmapss" / "train_FD001.txt"


def _library(rng: np.random.Generator, m: int = 5, n: int = 4) -> tuple[np.ndarray, np.ndarray]:
    H = rng.normal(size=(m, n))
    A = rng.normal(size=(m, m))
    return H, A @ A.T + m * np.eye(m)


def test_attribution_is_the_weighted_least_squares_fit_of_each_fault() -> None:
    rng = np.random.default_rng(1)
    H, W = _library(rng)
    d = rng.normal(size=(6, H.shape[0]))
    wssr, f = wear.attribute(d, W, H)
    L = np.linalg.cholesky(W)  # W = L L^T: the weighted fit is an ordinary one in L^T
    for k in range(d.shape[0]):
        for i in range(H.shape[1]):
            x, res, *_ = np.linalg.lstsq(L.T @ H[:, i : i + 1], L.T @ d[k], rcond=None)
            assert f[k, i] == pytest.approx(x[0], rel=1e-10)
            assert wssr[k, i] == pytest.approx(res[0], rel=1e-8)


def test_a_change_along_one_fault_is_that_fault_with_zero_wssr() -> None:
    rng = np.random.default_rng(2)
    H, W = _library(rng)
    wssr, f = wear.attribute(2.5 * H[:, 2], W, H)
    assert f[0, 2] == pytest.approx(2.5) and wssr[0, 2] == pytest.approx(0.0, abs=1e-9)
    assert wear.best_fault(wssr, f, np.ones(4, bool))[0] == 2
    # Not a candidate, or the opposite direction: not attributed to it.
    assert wear.best_fault(wssr, f, np.array([1, 1, 0, 1], bool))[0] != 2
    w2, f2 = wear.attribute(-2.5 * H[:, 2], W, H)
    assert wear.best_fault(w2, f2, np.ones(4, bool))[0] != 2


def test_vectorised_cusum_is_the_recursion() -> None:
    rng = np.random.default_rng(3)
    H, W = _library(rng)
    S = 300
    x = np.cumsum(rng.normal(scale=0.02, size=(S, H.shape[0])), axis=0)
    cycles = np.arange(S) // 2  # two records a flight
    cfg = wear.WearSettings(settle=5, n_base=20, limit=1e9, margin=1e9, rate=1e-3)
    scan = wear.wear_scan(x, H, W, cycles.astype(float), settings=cfg)
    f = scan.f
    start = cfg.settle + cfg.n_base - 1
    g = np.zeros(H.shape[1])
    for k in range(start + 1, S):
        g = np.maximum(0.0, g + (f[k] - f[k - 1]) - cfg.rate * (cycles[k] - cycles[k - 1]))
        np.testing.assert_allclose(scan.g[k], g, atol=1e-12)


def test_linear_drift_along_a_fault_is_alerted_and_attributed_to_it() -> None:
    rng = np.random.default_rng(4)
    H, W = _library(rng)
    S, onset, true_fault = 600, 200, 1
    noise = rng.normal(scale=0.01, size=(S, H.shape[0]))
    drift = np.clip(np.arange(S) - onset, 0, None)[:, None] * 0.004 * H[:, true_fault]
    resets = np.zeros(S, bool)
    scan = wear.wear_scan(noise + drift, H, W, np.arange(S, dtype=float), resets)
    assert len(scan.alerts) == 1
    alert = scan.alerts[0]
    assert alert.kind == wear.RATE and alert.fault == true_fault
    assert onset < alert.index < onset + 100
    assert alert.wssr[true_fault] == alert.wssr.min()
    # After a maintenance reset the baseline restarts: a second stretch, a second alert.
    resets[400] = True
    again = wear.wear_scan(noise + drift, H, W, np.arange(S, dtype=float), resets)
    assert [a.fault for a in again.alerts] == [true_fault, true_fault]
    assert again.alerts[1].baseline_start == 400 + wear.WearSettings().settle


def test_explained_share_is_the_fits_part_of_the_change() -> None:
    """``explained`` with ``change_energy``: h_i^T W h_i f_i^2 / d^T W d, the change's own
    weighted norm computed here; 1 along a fault, 0 for no change."""
    rng = np.random.default_rng(5)
    H, W = _library(rng)
    d = rng.normal(size=(3, H.shape[0]))
    d[1] = 0.7 * H[:, 2]
    wssr, f = wear.attribute(d, W, H)
    total = np.einsum("km,mn,kn->k", d, W, d)
    np.testing.assert_allclose(wear.change_energy(wssr, f, W, H), total[:, None] + 0 * f,
                               rtol=1e-12)
    share = wear.explained(wssr, total[:, None])
    for k in range(3):
        for i in range(H.shape[1]):
            h = H[:, i]
            assert share[k, i] == pytest.approx((h @ W @ h) * f[k, i] ** 2 / (d[k] @ W @ d[k]))
    assert share[1, 2] == pytest.approx(1.0)
    assert wear.explained(np.zeros(4), 0.0).max() == 0.0


def test_a_limit_alert_needs_a_change_of_the_faults_kind() -> None:
    """A change whose magnitude along a fault reaches the limit while the fault explains a
    tenth of it (estimates wandering across the fault's direction as well) raises no limit
    alert, in the scan and record by record; the same change along the fault alone does."""
    rng = np.random.default_rng(6)
    H, W = _library(rng, n=1)
    m = H.shape[0]
    h = H[:, 0]
    a = h @ W @ h
    v = rng.normal(size=m)
    v -= (h @ W @ v) / a * h  # W-orthogonal to h: no part of it along the fault
    v *= np.sqrt(9.0 * 1.2**2 * a / (v @ W @ v))  # nine times the fault's part
    S, onset = 400, 100
    ramp = np.clip(np.arange(S) - onset, 0, None)[:, None] / (S - onset)
    cfg = wear.WearSettings(margin=1e6)  # the rate CUSUM never alerts: the limit alone
    det = wear.WearDetector(H, W, np.ones(1, bool), cfg)
    noise = rng.normal(scale=1e-3, size=(S, m))
    for change, alerted in ((1.2 * h, True), (1.2 * h + v, False)):
        x = noise + ramp * change
        scan = wear.wear_scan(x, H, W, np.arange(S, dtype=float), np.zeros(S, bool),
                              settings=cfg)
        steps = wear.wear_steps(det, wear.WearState(), x, np.ones(S, bool), np.zeros(S, bool))
        assert [a.kind for a in scan.alerts] == ([wear.LIMIT] if alerted else [])
        assert [_alert_key(a) for a in steps.alerts] == [_alert_key(a) for a in scan.alerts]
        wssr, f = wear.attribute(change[None, :], W, H)
        assert f[0, 0] == pytest.approx(1.2)
        share = wear.explained(wssr, wear.change_energy(wssr, f, W, H))
        assert share[0, 0] == pytest.approx(1.0 if alerted else 0.1)


def test_an_alert_due_on_held_records_comes_on_the_first_record_after() -> None:
    """``wear_steps`` with records held (the pipeline's shift alarm awaiting isolation): no
    alert on them, the CUSUMs going on, so an alert due there comes on the first record after
    the hold, the same alert otherwise; a hold before the alert changes nothing."""
    rng = np.random.default_rng(4)
    H, W = _library(rng)
    S, onset, true_fault = 600, 200, 1
    noise = rng.normal(scale=0.01, size=(S, H.shape[0]))
    x = noise + np.clip(np.arange(S) - onset, 0, None)[:, None] * 0.004 * H[:, true_fault]
    det = wear.WearDetector(H, W, np.ones(H.shape[1], bool))
    flights, resets = np.ones(S, bool), np.zeros(S, bool)
    (free,) = wear.wear_steps(det, wear.WearState(), x, flights, resets).alerts
    hold = np.zeros(S, bool)
    hold[free.index - 3 : free.index + 7] = True
    (held,) = wear.wear_steps(det, wear.WearState(), x, flights, resets, hold=hold).alerts
    assert held.index == free.index + 7
    assert (held.kind, held.fault) == (free.kind, free.fault)
    early = np.zeros(S, bool)
    early[100:150] = True
    (same,) = wear.wear_steps(det, wear.WearState(), x, flights, resets, hold=early).alerts
    assert _alert_key(same) == _alert_key(free)


def test_noise_alone_alarms_at_the_cusum_design_rate() -> None:
    """White increments N(0, s^2) of the magnitude, reference k s and threshold h s: Page's
    CUSUM, whose mean run length Siegmund approximates as
    (exp(2 k b) - 2 k b - 1) / (2 k^2), b = h + 1.166 (within a few percent)."""
    rng = np.random.default_rng(5)
    k, h, s = 0.5, 3.0, 0.01
    b = h + 1.166
    arl = (np.exp(2 * k * b) - 2 * k * b - 1) / (2 * k * k)
    cfg = wear.WearSettings(settle=0, n_base=10, limit=1e9, rate=k * s, margin=0.0,
                            margin_floor=h * s)
    H, W = np.eye(1), np.eye(1)
    S = 2000
    runs = []
    for _ in range(600):
        x = np.cumsum(rng.normal(scale=s, size=(S, 1)), axis=0)
        alerts = wear.wear_scan(x, H, W, np.arange(S, dtype=float), settings=cfg).alerts
        assert alerts  # P(no alarm in 2000 records) ~ exp(-2000 / 119)
        runs.append(alerts[0].index - (cfg.settle + cfg.n_base - 1))
    mean = float(np.mean(runs))
    se = float(np.std(runs)) / np.sqrt(len(runs))
    assert abs(mean - arl) < max(4 * se, 0.08 * arl), (mean, arl, se)


def test_directional_bank_alerts_a_sensor_drift_sooner_and_names_the_fault() -> None:
    rng = np.random.default_rng(8)
    H, W = _library(rng)
    ny, S, onset, true_fault = 6, 600, 200, 1
    sig = rng.normal(size=(ny, H.shape[1]))
    ramp = np.clip(np.arange(S) - onset, 0, None)[:, None] * 0.004
    x = rng.normal(scale=0.01, size=(S, H.shape[0])) + ramp * H[:, true_fault]
    dy = rng.normal(size=(S, ny)) + 25.0 * ramp * sig[:, true_fault]
    cycles = np.arange(S, dtype=float)
    day = {"epoch": 86400.0 * cycles}  # one record a day (as C-MAPSS cycles are imported)
    # A fast drift (the true fault's matched filter gains about a quarter of a standard
    # deviation a record): a bank referenced to a one-standard-deviation shift, and the
    # default (0.25, for slow wear); with their calibrated thresholds both cross at the same
    # record here, before the tuners' own alerts.
    cfg = wear.WearSettings(bank_reference=0.5)
    scan = wear.wear_scan(x, H, W, cycles, settings=cfg, dy=dy, var=np.ones(ny), signatures=sig,
                          **day)
    assert scan.bank is not None and len(scan.alerts) == 1
    alert = scan.alerts[0]
    assert alert.kind == wear.DIRECTIONAL and alert.fault == true_fault
    tuners_only = wear.wear_scan(x, H, W, cycles, settings=cfg).alerts[0]
    assert onset < alert.index < tuners_only.index
    assert alert.statistic > alert.threshold
    default = wear.wear_scan(x, H, W, cycles, dy=dy, var=np.ones(ny), signatures=sig,
                             **day).alerts
    assert default[0].fault == true_fault and alert.index <= default[0].index
    assert default[0].index < tuners_only.index
    # Per-record signatures [S, ny, n] are the same bank.
    again = wear.wear_scan(x, H, W, cycles, settings=cfg, dy=dy, var=np.ones((S, ny)),
                           signatures=np.broadcast_to(sig, (S, ny, sig.shape[1])), **day)
    assert again.alerts[0].index == alert.index
    np.testing.assert_allclose(again.bank, scan.bank)


@pytest.mark.parametrize("n", [1, 4])
def test_directional_bank_false_alarms_at_the_family_wise_rate(n: int) -> None:
    """White matched-filter outputs on n orthogonal signatures, no confidence condition: each
    CUSUM is Page's (reference k, threshold h in standard deviations) with Siegmund's mean run
    length ARL (as above); the first of n independent ones comes after about ARL / n records
    (the run lengths nearly exponential). A long baseline keeps the standardisation's own
    error small (its bias on the run length about 4 %)."""
    rng = np.random.default_rng(9 + n)
    k, h = 0.5, 3.0
    b = h + 1.166
    arl = (np.exp(2 * k * b) - 2 * k * b - 1) / (2 * k * k)
    cfg = wear.WearSettings(settle=0, n_base=1000, limit=1e9, bank_reference=k,
                            bank_threshold=h, bank_rate=0.0, confidence=0.0, bank_alpha=0.0)
    S = cfg.n_base + 2500
    runs = []
    for _ in range(400):
        dy = rng.normal(size=(S, n))
        alerts = wear.wear_scan(np.zeros((S, n)), np.eye(n), np.eye(n),
                                np.arange(S, dtype=float), settings=cfg, dy=dy,
                                var=np.ones(n), signatures=np.eye(n)).alerts
        assert alerts and alerts[0].kind == wear.DIRECTIONAL
        runs.append(alerts[0].index - (cfg.n_base - 1))
    mean = float(np.mean(runs))
    se = float(np.std(runs)) / np.sqrt(len(runs))
    assert abs(mean - arl / n) < max(4 * se, 0.1 * arl / n), (mean, arl / n, se)


def test_signature_cusum_is_the_recursion_on_the_matched_filter() -> None:
    rng = np.random.default_rng(6)
    S, ny = 300, 4
    g = np.array([1.0, -0.5, 0.3, 0.0])
    var = np.array([1.0, 2.0, 0.5, 1.0])
    dy = rng.normal(size=(S, ny)) * np.sqrt(var)
    dy[150:] += 1.5 * g
    dy[7, 1] = np.nan  # a missing value drops out of that record's projection
    for arm_at in (0, 50, 200):
        got = wear.signature_cusum(dy, var, g, arm_at=arm_at)
        z = np.empty(S)
        for k in range(S):
            ok = np.isfinite(dy[k])
            z[k] = np.sum(g[ok] * dy[k, ok] / var[ok]) / np.sqrt(np.sum(g[ok] ** 2 / var[ok]))
        z = (z - z[:30].mean()) / z[:30].std(ddof=1)
        cusum, want = 0.0, None
        for k in range(S):
            cusum = max(0.0, cusum + z[k] - 0.5)
            if cusum > 5.0 and k >= arm_at:
                want = k
                break
        assert got == want
    late = wear.signature_cusum(dy, var, g, arm_at=200)
    assert late is not None and late >= 200


@pytest.fixture(scope="module")
def fd001_figures() -> dict[str, object]:
    """All 100 FD001 train engines (the targets are on the whole set; about 10 s). On the
    first 20 alone the median lead is 125.5 against the naive CUSUM's 126.5."""
    from tests.support import fd001_replay

    est = fd001_replay.fd001_estimator(fd001_replay.fd001_schedule())
    engines = fd001_replay.fd001_runs(FD001, est, None)
    tracks = fd001_replay.filter_tracks(est, [e.run for e in engines])
    W = wear.health_weight(est.Vp)
    p = len(est.layout.health)
    cand = np.all(est.S_full[p:] == 0.0, axis=0)
    hpc = est.layout.faults.index("HPC")
    ours, naive, faults = [], [], []
    for e, tr in zip(engines, tracks, strict=True):
        dy, var, sig = fd001_replay.sensor_deviations(est, e.run)
        alerts = wear.wear_scan(tr.q, est.H, W, e.cycle.astype(float), candidates=cand,
                                dy=dy, var=var, signatures=sig, epoch=e.run.epoch).alerts
        if alerts:
            ours.append(int(e.cycle[-1] - e.cycle[alerts[0].index]))
            faults.append(alerts[0].fault)
        j = wear.signature_cusum(dy, var, sig[0, :, hpc])
        if j is not None:
            naive.append(int(e.cycle[-1] - e.cycle[j]))
    return {"n": len(engines), "ours": ours, "naive": naive, "faults": faults, "hpc": hpc}


@pytest.mark.skipif(not FD001.exists(), reason=f"no C-MAPSS file at {FD001}")
def test_fd001_every_engine_alerted_before_failure_and_attributed_to_hpc(
    fd001_figures: dict[str, object],
) -> None:
    f = fd001_figures
    ours, faults = f["ours"], f["faults"]
    assert isinstance(ours, list) and isinstance(faults, list)
    assert len(ours) == f["n"] and min(ours) > 0
    assert sum(x == f["hpc"] for x in faults) >= 0.9 * len(faults)


@pytest.mark.skipif(not FD001.exists(), reason=f"no C-MAPSS file at {FD001}")
@pytest.mark.xfail(strict=True, reason=(
    "the bank alone (``wear_scan``: no fleet direction; the product's fleet CUSUM meets the "
    "target, tests/app/services/snapshots/test_wear_events.py): "
    "with the bank's threshold calibrated by Monte Carlo to the issue's budget "
    "(1 false alert per engine-year from a stretch's start; one record a day: h = 4.35) the "
    "bank crosses a median 119.5 cycles before failure, the naive CUSUM 121.5, and the "
    "attribution's wait for a confident fault (WSSR ratio 1.3, 91 % HPC) leaves 112.5; a "
    "lower ratio names HPC on fewer than 90 % (bench/bench_wear.py)"))
def test_fd001_median_lead_at_least_the_naive_signature_cusum(
    fd001_figures: dict[str, object],
) -> None:
    ours, naive = fd001_figures["ours"], fd001_figures["naive"]
    assert isinstance(ours, list) and isinstance(naive, list)
    assert len(naive) == fd001_figures["n"]
    assert np.median(ours) >= np.median(naive)


def _alert_key(a: wear.WearAlert) -> tuple[object, ...]:
    return (a.index, a.kind, a.fault, round(a.magnitude, 9), round(a.statistic, 5))


@pytest.mark.parametrize("bank", [False, True])
@pytest.mark.parametrize("seed", [11, 12, 13])
def test_record_by_record_steps_give_the_scans_alerts_however_split(
    bank: bool, seed: int
) -> None:
    """``wear_steps`` against ``wear_scan`` on drifting engines with resets and two records a
    flight, dated (the bank's threshold from each stretch's record rate, parked for 40 days
    within two baselines); then the same records in random pieces, each continuing from the
    state the last left: the same alerts (the bank's sums are quantised to 2^-24:
    statistics to 1e-5) and bit-identical final states."""
    rng = np.random.default_rng(seed)
    H, W = _library(rng)
    m, n = H.shape
    S, ny = 900, 6
    drift = np.zeros((S, m))
    drift[400:] = np.outer(np.arange(S - 400), 4e-3 * H[:, seed % (n - 1)])
    x = drift + rng.normal(scale=0.05, size=(S, m))
    new_cycle = np.r_[True, rng.random(S - 1) < 0.5]
    resets = np.zeros(S, bool)
    resets[[250, 700]] = True
    cfg = wear.WearSettings(margin=6.0, limit=0.8)
    cand = np.array([True] * (n - 1) + [False])
    sensors: dict[str, np.ndarray] = {}
    z = None
    if bank:
        sig = rng.normal(size=(ny, n))
        dy = rng.normal(size=(S, ny))
        dy[400:] += np.outer(np.arange(S - 400) * 1e-2, sig[:, seed % (n - 1)])
        var = np.ones(ny)
        sensors = {"dy": dy, "var": var, "signatures": sig}
        z = wear.matched_rows(dy, var, sig)
    cycles = np.cumsum(new_cycle).astype(float)
    gaps = np.where(new_cycle, rng.uniform(4.0, 30.0, S) * 3600.0, 1800.0)
    gaps[[20, 270]] += 40 * 86400.0
    epoch = 1.7e9 + np.cumsum(gaps)
    scan = wear.wear_scan(x, H, W, cycles, resets, cand, cfg, epoch=epoch, **sensors)
    assert scan.alerts, "the drift should alert"
    assert (wear.DIRECTIONAL in {a.kind for a in scan.alerts}) == bank
    det = wear.WearDetector(H, W, cand, cfg)
    whole = wear.wear_steps(det, wear.WearState(), x, new_cycle, resets, z, epoch=epoch)
    assert [_alert_key(a) for a in whole.alerts] == [_alert_key(a) for a in scan.alerts]
    cuts = np.sort(rng.choice(np.arange(1, S), size=25, replace=False))
    _assert_split_equals_whole(det, whole, cuts, x, new_cycle, resets, z, epoch=epoch)


def test_bank_threshold_is_set_by_the_false_alerts_per_engine_year() -> None:
    """Uncalibrated, h solves Siegmund's ARL(kappa', h) = n * bank_arl, kappa' the reference
    with the baseline allowance and bank_arl = records per engine-year / false alerts per
    engine-year (the nominal rate, or the one given); bank_arl set overrides; bank_alpha = 0
    leaves the reference and scale as given. Calibrated (the default), h is the bank's Monte
    Carlo quantile (``calibrated_threshold``), below Siegmund's with Bonferroni."""
    cfg = wear.WearSettings(bank_calibrated=False)
    d = wear.bank_design(cfg, 5)
    assert d.reference == pytest.approx(cfg.bank_reference + 1.6449 / np.sqrt(cfg.n_base),
                                        rel=1e-4)
    assert d.scale > 1.0
    nominal = cfg.records_per_year / cfg.false_alerts_per_year
    assert wear.bank_arl(cfg) == nominal
    assert wear.siegmund_arl(d.reference, d.threshold) == pytest.approx(5 * nominal,
                                                                         rel=1e-9)
    # One record a day: a false crossing every engine-year is 365.25 records.
    daily = wear.bank_design(cfg, 5, 365.25)
    assert wear.siegmund_arl(daily.reference, daily.threshold) == pytest.approx(
        5 * 365.25, rel=1e-9)
    assert daily.threshold < d.threshold
    fixed = replace(cfg, bank_arl=1000.0)
    assert wear.bank_design(fixed, 5, 365.25) == wear.bank_design(fixed, 5)
    plain = wear.bank_design(wear.WearSettings(bank_alpha=0.0, bank_threshold=2.0), 5)
    assert (plain.reference, plain.scale, plain.threshold) == (cfg.bank_reference, 1.0, 2.0)
    calibrated = wear.bank_design(replace(cfg, bank_calibrated=True), 5, 365.25)
    assert (calibrated.reference, calibrated.scale) == (daily.reference, daily.scale)
    assert calibrated.threshold == wear.calibrated_threshold(
        5, daily.reference, daily.scale, cfg.n_base, cfg.bank_rate, 365.25, 365.25)
    assert 0.5 * daily.threshold < calibrated.threshold < daily.threshold


def test_calibrated_bank_false_crossings_at_the_designed_rate() -> None:
    """White matched-filter outputs on 5 orthogonal signatures, one record a day (365 a year),
    no confidence condition, fresh noise (not the calibration's seed): at every horizon T up
    to an engine-year the share of engines whose bank has crossed within T armed records is
    at most the design's 1 - exp(-T / ARL) (ARL = 365 records: 1 false alert per engine-year)
    within sampling error, and at the short horizons that bind it is about that: the
    calibration is not conservative (Siegmund's threshold with Bonferroni, higher, is crossed
    less often on the same noise)."""
    rng = np.random.default_rng(57)
    n, engines = 5, 300
    cfg = wear.WearSettings(confidence=0.0, limit=1e9)
    b1 = cfg.settle + cfg.n_base
    S = b1 + 365
    cycles = np.arange(S, dtype=float)
    epoch = 86400.0 * cycles
    arl = wear.bank_arl(cfg, 365.25)
    first = []
    for _ in range(engines):
        alerts = wear.wear_scan(np.zeros((S, n)), np.eye(n), np.eye(n), cycles, settings=cfg,
                                dy=rng.normal(size=(S, n)), var=np.ones(n),
                                signatures=np.eye(n), epoch=epoch).alerts
        first.append(alerts[0].index - b1 + 1 if alerts else np.inf)
    runs = np.asarray(first)
    binding = []
    for T in (10, 20, 50, 100, 200, 365):
        p = -np.expm1(-T / arl)
        sd = np.sqrt(engines * p * (1.0 - p))
        crossed = int(np.sum(runs <= T))
        assert crossed <= engines * p + 3.0 * sd, (T, crossed, engines * p)
        binding.append(crossed >= engines * p - 2.0 * sd)
    assert any(binding[:3]), runs


def test_short_baseline_bank_false_alarms_within_its_design() -> None:
    """White matched-filter outputs on 4 orthogonal signatures, the bank's baseline 30
    records (its mean and standard deviation then err by about 0.18 and 13 %, errors every
    later record shares), no confidence condition: the share of engines with a crossing in
    T armed records stays within the design's 1 - exp(-T / bank_arl) (Bonferroni over the
    bank: an upper bound) plus sampling error, with
    Siegmund's threshold (uncalibrated: the bound the calibration replaces). Without the
    allowance for the baseline's error (bank_alpha = 0) the same threshold is crossed far
    more often than designed."""
    rng = np.random.default_rng(21)
    n, engines, T = 4, 300, 300
    base = wear.WearSettings(confidence=0.0, limit=1e9, bank_rate=0.0, bank_arl=1000.0,
                             bank_calibrated=False)
    b1 = base.settle + base.n_base
    S = b1 + T
    design = 1.0 - np.exp(-T / base.bank_arl)
    h = wear.bank_design(base, n).threshold
    counts = {}
    for alpha in (base.bank_alpha, 0.0):
        cfg = replace(base, bank_alpha=alpha, bank_threshold=h)
        hits = 0
        for _ in range(engines):
            alerts = wear.wear_scan(np.zeros((S, n)), np.eye(n), np.eye(n),
                                    np.arange(S, dtype=float), settings=cfg,
                                    dy=rng.normal(size=(S, n)), var=np.ones(n),
                                    signatures=np.eye(n)).alerts
            hits += bool(alerts)
        counts[alpha] = hits
    allowed = engines * design + 3 * np.sqrt(engines * design * (1 - design))
    assert counts[base.bank_alpha] <= allowed, (counts, engines * design)
    assert counts[0.0] > allowed, (counts, engines * design)


def test_naive_signature_cusum_false_alarms_at_over_half_the_budget() -> None:
    """The peer of the FD001 lead on white matched-filter outputs, 50 records then 350 armed
    (about an engine-year at one record a day, as FD001 is imported): the naive CUSUM (its
    30-record baseline taken as exact, reference 0.5, threshold 5, one direction) alarms on
    about 43 % of the engines, over half the issue's budget of one false alert per
    engine-year (1 - exp(-0.5 * 350 / 365.25) = 38 %) for one direction and without naming
    a fault; the bank's design spends the whole budget on all its candidates."""
    rng = np.random.default_rng(31)
    engines, records = 600, 400
    half = -np.expm1(-0.5 * (records - 50) / 365.25)
    hits = sum(wear.signature_cusum(rng.normal(size=(records, 1)), np.ones(1), np.ones(1))
               is not None for _ in range(engines))
    assert hits > half * engines, (hits, half * engines)


def test_record_rate_counts_the_records_of_the_time_flown() -> None:
    """Records per engine-year from the gaps between records, those of 30 days or more (the
    engine on the ground) left out; None without time to measure."""
    day = 86400.0
    twice_a_day = 43200.0 * np.arange(50)
    assert wear.record_rate(twice_a_day) == pytest.approx(2 * 365.25)
    parked = np.r_[twice_a_day, twice_a_day[-1] + 60 * day + 43200.0 * np.arange(10)]
    assert wear.record_rate(parked) == pytest.approx(2 * 365.25)
    assert wear.record_rate(np.zeros(5)) is None and wear.record_rate(np.ones(1)) is None


def test_the_measured_record_rate_sets_the_banks_threshold_in_scan_and_steps() -> None:
    """The same healthy records dated once a day and four times a day: the bank's threshold
    (the alert's) is the rate's design, in ``wear_scan`` and in ``wear_steps`` alike."""
    rng = np.random.default_rng(41)
    H, W = _library(rng)
    m, n = H.shape
    S, ny = 200, 6
    sig = rng.normal(size=(ny, n))
    x = rng.normal(scale=0.01, size=(S, m))
    x[60:] += np.outer(np.arange(S - 60) * 0.02, H[:, 0])
    dy = rng.normal(size=(S, ny))
    dy[60:] += np.outer(np.arange(S - 60) * 0.05, sig[:, 0])
    cycles = np.arange(S, dtype=float)
    cfg = wear.WearSettings(confidence=0.0)
    det = wear.WearDetector(H, W, np.ones(n, bool), cfg)
    z = wear.matched_rows(dy, np.ones((S, ny)), sig)
    for per_day in (1.0, 4.0):
        epoch = 1.7e9 + cycles * 86400.0 / per_day
        scan = wear.wear_scan(x, H, W, cycles, settings=cfg, dy=dy, var=np.ones(ny),
                              signatures=sig, epoch=epoch).alerts
        steps = wear.wear_steps(det, wear.WearState(), x, np.ones(S, bool), np.zeros(S, bool),
                                z, epoch=epoch).alerts
        want = wear.bank_design(cfg, n, 365.25 * per_day).threshold
        assert scan and steps and scan[0].kind == wear.DIRECTIONAL
        assert scan[0].threshold == pytest.approx(want, rel=1e-12)
        assert steps[0].threshold == pytest.approx(want, rel=1e-12)
        assert (steps[0].index, steps[0].fault) == (scan[0].index, scan[0].fault)
    # Undated records, or a state stored before the rate was measured: the nominal rate's.
    nominal = wear.bank_design(cfg, n).threshold
    undated = wear.wear_steps(det, wear.WearState(), x, np.ones(S, bool), np.zeros(S, bool), z)
    assert undated.alerts[0].threshold == nominal
    first = wear.wear_steps(det, wear.WearState(), x[:55], np.ones(55, bool), np.zeros(55, bool),
                            z[:55], epoch=epoch[:55]).state
    assert first.bank_h is not None and first.x0 is not None and not first.alerted
    later = wear.wear_steps(det, wear.replace_state(first, bank_h=None), x[55:],
                            np.ones(S - 55, bool), np.zeros(S - 55, bool), z[55:]).alerts
    assert later[0].threshold == nominal


def test_an_empty_fault_library_attributes_nothing_and_counts_the_cycles() -> None:
    """A design whose library keeps no fault (an engine type whose health parameters no
    library fault fits): the detector runs, raises nothing and keeps counting flights."""
    rng = np.random.default_rng(3)
    S, m = 400, 3
    det = wear.WearDetector(np.zeros((m, 0)), np.eye(m), np.zeros(0, bool))
    x = -np.linspace(0.0, 3.0, S)[:, None] * np.ones(m) + 0.05 * rng.normal(size=(S, m))
    run = wear.wear_steps(det, wear.WearState(), x, np.ones(S, bool), np.zeros(S, bool),
                          np.zeros((S, 0)), keep=[9, 299])
    assert run.alerts == () and run.state.cycle == S
    assert [(j, st.cycle) for j, st in run.states] == [(9, 10.0), (299, 300.0)]


# --- The fleet CUSUM: a direction learnt from other engines' drifts.


def test_fault_drift_splits_a_change_over_the_candidates_and_latest_drift_is_its_tail() -> None:
    """A tuner change H c is the candidates' magnitudes c (zero for the others); an engine's
    drift is the fit of its last ``drift_tail`` armed records' mean less its baseline, the
    same whether its records come in one run or in pieces (a short last piece keeps the
    previous run's drift), and a reset starts it again."""
    rng = np.random.default_rng(3)
    H, W = _library(rng)
    cand = np.array([True, True, True, False])
    det = wear.WearDetector(H, W, cand, wear.WearSettings())
    c = np.array([0.5, -0.2, 1.0, 0.0])
    assert np.allclose(wear.fault_drift(det, H @ c), c)
    cfg = det.settings
    S = 200
    x = rng.normal(scale=0.01, size=(S, H.shape[0])) + np.outer(np.arange(S) / S, H @ c)
    resets = np.zeros(S, bool)
    b1 = cfg.settle + cfg.n_base
    expect = wear.fault_drift(det, x[-cfg.drift_tail :].mean(axis=0) - x[cfg.settle : b1].mean(0))
    assert np.allclose(wear.latest_drift(det, wear.WearState(), x, resets), expect)
    assert wear.latest_drift(det, wear.WearState(), x[:b1 + 5], resets[:b1 + 5]) is None
    for cut in (30, 120):  # within the baseline, after it
        run = wear.wear_steps(det, wear.WearState(), x[:cut], np.ones(cut, bool),
                              resets[:cut])
        assert np.allclose(wear.latest_drift(det, run.state, x[cut:], resets[cut:]), expect)
    run = wear.wear_steps(det, wear.WearState(), x[:190], np.ones(190, bool), resets[:190])
    first = replace(run.state, drift=wear.latest_drift(det, wear.WearState(), x[:190],
                                                       resets[:190]))
    assert first.drift is not None
    assert wear.latest_drift(det, first, x[190:], resets[190:]) == first.drift
    again = resets.copy()
    again[150] = True
    assert wear.latest_drift(det, first, x[100:], again[100:]) is None


def test_fleet_direction_is_the_mean_unit_drift_of_enough_engines() -> None:
    drifts = [np.array([2.0, 0.0, 0.0]), (0.0, 3.0, 0.0), np.zeros(3)]
    v = wear.fleet_direction(drifts)
    assert v is not None and np.allclose(v, np.array([1.0, 1.0, 0.0]) / np.sqrt(2.0))
    assert wear.fleet_direction(drifts, least=3) is None  # a zero drift counts for nothing
    assert wear.fleet_direction([]) is None
    assert wear.fleet_direction([(1.0, 0.0), (-1.0, 0.0)]) is None


def test_matched_filter_along_a_direction_is_the_filter_on_its_signature() -> None:
    rng = np.random.default_rng(4)
    S, ny, n = 50, 6, 4
    sig = rng.normal(size=(S, ny, n))
    dy = rng.normal(size=(S, ny))
    dy[3, 2] = np.nan
    var = rng.uniform(0.5, 2.0, size=(S, ny))
    cand = np.array([True, False, True, True])
    v = np.array([0.6, 0.0, -0.3, 0.74])
    parts = wear.matched_parts(dy, var, sig, cand)
    expect = wear.matched_rows(dy, var, sig @ v[:, None])[:, 0]
    assert np.allclose(wear.along(parts, v, cand), expect, rtol=1e-12, atol=1e-12)
    half = wear.matched_parts(dy[:20], var[:20], sig[:20], cand)
    assert np.array_equal(wear.along(half, v, cand), wear.along(parts, v, cand)[:20])


def _fleet_engine(seed: int, slope: float) -> tuple[
    wear.WearDetector, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray
]:
    """An engine drifting along a mix of two faults from record 300 in tuners and sensors
    (the fleet's kind of wear), a reset at 700: detector, x, new_cycle, resets, z, the
    fleet direction and the records' projections on it."""
    rng = np.random.default_rng(seed)
    H, W = _library(rng)
    m, n = H.shape
    S, ny = 900, 6
    v = np.array([0.0, 0.8, 0.6, 0.0])
    cand = np.array([True, True, True, False])
    x = rng.normal(scale=0.05, size=(S, m))
    x[300:] += np.outer(np.arange(S - 300) * 4e-3 * slope, H @ v)
    sig = rng.normal(size=(ny, n))
    dy = rng.normal(size=(S, ny))
    dy[300:] += np.outer(np.arange(S - 300) * 1e-2 * slope, sig @ v)
    var = np.ones((S, ny))
    resets = np.zeros(S, bool)
    resets[700] = True
    new_cycle = np.r_[True, rng.random(S - 1) < 0.5]
    det = wear.WearDetector(H, W, cand, wear.WearSettings(confidence=1.0))
    z = wear.matched_rows(dy, var, sig)
    zf = wear.along(wear.matched_parts(dy, var, sig, cand), v, cand)
    return det, x, new_cycle, resets, z, v, zf


@pytest.mark.parametrize("seed", [21, 22])
def test_fleet_cusum_alerts_the_fleets_wear_however_split(seed: int) -> None:
    """A drift along the fleet direction is alerted by the fleet CUSUM (kind ``fleet``, the
    fault the direction is attributed to), no later than by the bank alone; the bank's and the
    fleet CUSUM's thresholds split the budget; the records in random pieces, each from the
    last one's state, give the same alerts and state; a stretch under way keeps its
    direction (another one refused) and the stretch after the reset adopts it again."""
    det, x, new_cycle, resets, z, v, zf = _fleet_engine(seed, 0.5)
    S = len(x)
    whole = wear.wear_steps(det, wear.WearState(), x, new_cycle, resets, z, direction=v, zf=zf)
    alone = wear.wear_steps(det, wear.WearState(), x, new_cycle, resets, z)
    assert whole.alerts and whole.alerts[0].kind == wear.FLEET
    assert whole.alerts[0].fault == wear.fleet_fault(det, v) >= 0
    assert whole.alerts[0].statistic > whole.alerts[0].threshold
    assert alone.alerts and whole.alerts[0].index <= alone.alerts[0].index
    assert whole.state.direction == tuple(v.tolist())
    cfg = det.settings
    n_cand = int(det.candidates.sum())
    assert whole.alerts[0].threshold == wear.bank_design(
        replace(cfg, false_alerts_per_year=cfg.fleet_share), 1).threshold
    split_h = wear.bank_design(replace(cfg, false_alerts_per_year=1.0 - cfg.fleet_share),
                               n_cand).threshold
    assert split_h > wear.bank_design(cfg, n_cand).threshold
    rng = np.random.default_rng(seed)
    cuts = np.sort(rng.choice(np.arange(1, S), size=20, replace=False))
    _assert_split_equals_whole(det, whole, cuts, x, new_cycle, resets, z, direction=v, zf=zf)
    mid = wear.wear_steps(det, wear.WearState(), x[:100], new_cycle[:100], resets[:100],
                          z[:100], direction=v, zf=zf[:100]).state
    with pytest.raises(ValueError, match="keeps its fleet direction"):
        wear.wear_steps(det, mid, x[100:], new_cycle[100:], resets[100:], z[100:],
                        direction=-v, zf=-zf[100:])


def test_fleet_alert_waits_for_a_change_of_the_fleets_kind() -> None:
    """An engine whose own change is another fault's (an abrupt shift of a module the fleet
    does not wear) crosses the fleet CUSUM but gets no fleet alert: that is the shift
    detector's (or the bank's, once attributed)."""
    det, x, new_cycle, resets, z, v, zf = _fleet_engine(23, 0.0)
    other = np.array([1.0, 0.0, 0.0, 0.0])  # a fault outside the fleet direction
    x = x.copy()
    x[300:] += 2.0 * det.H @ other
    zf = zf.copy()
    zf[300:] += 3.0  # its projection on the fleet's signature: a crossing
    run = wear.wear_steps(det, wear.WearState(), x, new_cycle, resets, z, direction=v, zf=zf)
    assert all(a.kind != wear.FLEET for a in run.alerts)
    assert run.state.direction is not None


def test_a_direction_adopted_only_when_attributed_to_a_fault() -> None:
    """The learnt direction a stretch adopts: enough drifts and a confident attribution of
    its tuner change (along one fault: that fault; halfway between two: none, and the bank
    keeps the whole budget)."""
    H, W = np.eye(5)[:, :4], np.eye(5)
    det = wear.WearDetector(H, W, np.array([True, True, True, False]), wear.WearSettings())
    one = [np.array([0.0, 1.0 + 0.01 * k, 0.0, 0.0]) for k in range(5)]
    assert wear.learnt_direction(det, one) == (0.0, 1.0, 0.0, 0.0)
    assert wear.fleet_fault(det, np.array([0.0, 1.0, 0.0, 0.0])) == 1
    assert wear.learnt_direction(det, one[:4]) is None  # fewer than fleet_min
    two = [np.array([1.0, 1.0, 0.0, 0.0])] * 5
    assert wear.fleet_fault(det, np.array([1.0, 1.0, 0.0, 0.0]) / np.sqrt(2.0)) == -1
    assert wear.learnt_direction(det, two) is None


def test_kept_calibrations_give_the_thresholds_computed_here(tmp_path):
    from functools import partial

    from app.engine_cache import arrays

    args = (4, 0.5, 1.1, 30, 0.0)
    wear.keep_calibrations(None)
    here = wear.calibrated_threshold(*args, arl=365.0, horizon=365.0)
    store = partial(arrays, tmp_path, "wear-bank")
    try:
        wear.keep_calibrations(store)
        built = wear.calibrated_threshold(*args, arl=365.0, horizon=365.0)
        assert len(list(tmp_path.glob("wear-bank-*.npz"))) == 1
        wear.bank_calibration.cache_clear()  # another process: reads the kept table
        read = wear.calibrated_threshold(*args, arl=365.0, horizon=365.0)
    finally:
        wear.keep_calibrations(None)
    assert here is not None and built == here and read == here


def _assert_split_equals_whole(det, whole, cuts, x, new_cycle, resets, z, direction=None,
                               **per_record):
    """``wear_steps`` over the records cut at ``cuts``, each part continuing the state the
    one before left, gives the whole run's alerts and final state (``per_record``: arrays
    cut with the records, such as epoch or zf)."""
    st, alerts = wear.WearState(), []
    for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(x)], strict=True):
        extra = {k: v[a:b] for k, v in per_record.items()}
        if direction is not None:
            extra["direction"] = direction
        part = wear.wear_steps(det, st, x[a:b], new_cycle[a:b], resets[a:b],
                               None if z is None else z[a:b], **extra)
        alerts += [(a + al.index, al.kind, al.fault, al.magnitude, al.statistic)
                   for al in part.alerts]
        st = part.state
    assert alerts == [(al.index, al.kind, al.fault, al.magnitude, al.statistic)
                      for al in whole.alerts]
    assert st == whole.state


def test_matched_sums_are_each_records_sums_by_hand() -> None:
    """``matched_sums`` (the pipeline's matched filter and the fleet direction's sums, over runs
    of records) equals each record's sensor-by-sensor sums written out one record at a time,
    bit for bit, with missing sensors left out and one signature for all records or one each."""
    rng = np.random.default_rng(21)
    S, ny, n = 7, 5, 4
    dy = rng.normal(size=(S, ny))
    dy[2, 1] = dy[5, 4] = np.nan
    var = rng.uniform(0.5, 2.0, (S, ny))
    cand = np.array([True, False, True, True])
    for sig in (rng.normal(size=(ny, n)), rng.normal(size=(S, ny, n))):
        sig_t = sig[..., None] if sig.ndim == 2 else sig.transpose(1, 2, 0)
        z, parts = wear.matched_sums(dy, var, np.ascontiguousarray(sig_t), cand)
        for k in range(S):
            s_k = sig if sig.ndim == 2 else sig[k]
            num, den = np.zeros(n), np.zeros(n)
            gram = np.zeros((3, 3))
            for j in range(ny):
                if np.isnan(dy[k, j]):
                    continue
                w = 1.0 / var[k, j]
                num = num + (w * dy[k, j]) * s_k[j]
                den = den + w * (s_k[j] * s_k[j])
                c = s_k[j, cand]
                gram = gram + w * np.outer(c, c)
            np.testing.assert_array_equal(z[k], num / np.sqrt(den))
            np.testing.assert_array_equal(parts.num[k], num[cand])
            np.testing.assert_array_equal(parts.gram[k], gram)

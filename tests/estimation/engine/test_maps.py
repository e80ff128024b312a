"""Component maps: monotone where they must be, stall line consistent."""

import numpy as np

from estimation.engine.design import engine_design
from estimation.engine.maps import compressor, stall_margin, stall_pressure_ratio, turbine


def _compressors():
    d = engine_design()
    return {"fan": d.fan, "lpc": d.lpc, "hpc": d.hpc}


def test_design_point_is_at_design_values():
    for m in _compressors().values():
        wc, pr, eff = compressor(m, np.array(1.0), np.array(0.5))
        assert np.isclose(wc, m.wc_design) and np.isclose(pr, m.pr_design)
        assert np.isclose(eff, m.eff_design)


def test_speed_lines_monotone():
    n = np.linspace(0.3, 1.1, 33)[:, None]
    beta = np.linspace(-0.5, 1.0, 31)[None, :]
    for name, m in _compressors().items():
        wc, pr, _ = compressor(m, n, beta)
        assert np.all(np.diff(wc, axis=1) < 0), name  # flow falls towards stall
        assert np.all(np.diff(pr, axis=1) > 0), name  # pressure ratio rises towards stall
        assert np.all(np.diff(wc, axis=0) > 0), name  # both rise with speed
        assert np.all(np.diff(pr, axis=0) > 0), name


def test_stall_line_is_beta_one():
    # The closed-form stall pressure ratio must equal the map's PR at beta = 1.
    n = np.linspace(0.3, 1.1, 17)
    for name, m in _compressors().items():
        for fs in (1.0, 0.97):
            wc, pr, _ = compressor(m, n, np.ones_like(n), fs)
            assert np.allclose(stall_pressure_ratio(m, wc, fs), pr, rtol=1e-12), name
            assert np.allclose(stall_margin(m, wc, pr, fs), 0.0, atol=1e-9), name
            wc2, pr2, _ = compressor(m, n, np.full_like(n, 0.5), fs)
            assert np.all(stall_margin(m, wc2, pr2, fs) > 0), name
        # stall pressure ratio rises with corrected flow
        w = np.linspace(0.2, 1.2, 50) * m.wc_design
        assert np.all(np.diff(stall_pressure_ratio(m, w)) > 0)


def test_efficiency_peaks_at_design():
    n = np.linspace(0.3, 1.1, 33)[:, None]
    beta = np.linspace(-0.5, 1.0, 31)[None, :]
    for m in _compressors().values():
        _, _, eff = compressor(m, n, beta)
        assert np.max(eff) <= m.eff_design + 1e-15
    d = engine_design()
    for m in (d.hpt, d.lpt):
        pr = np.linspace(1.2, 8.0, 60)
        _, eff = turbine(m, np.ones_like(pr), pr)
        assert np.max(eff) <= m.eff_design + 1e-15


def test_turbine_flow_rises_with_pressure_ratio_and_chokes():
    d = engine_design()
    for m in (d.hpt, d.lpt):
        pr = np.linspace(1.05, 10.0, 200)
        wc, _ = turbine(m, np.ones_like(pr), pr)
        assert np.all(np.diff(wc) > 0)
        # Ellipse law: the flow tends to Wc_d / sqrt(1 - PR_d^-2) at high PR.
        limit = m.wc_design / np.sqrt(1.0 - m.pr_design**-2)
        assert wc[-1] < limit and wc[-1] > 0.99 * limit


def test_health_scalars_scale_flow_and_efficiency():
    m = engine_design().hpc
    n, beta = np.array(0.9), np.array(0.4)
    wc0, pr0, eff0 = compressor(m, n, beta)
    wc1, pr1, eff1 = compressor(m, n, beta, 0.98, 0.97)
    assert np.isclose(wc1 / wc0, 0.98) and np.isclose(eff1 / eff0, 0.97) and pr1 == pr0

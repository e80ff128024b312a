"""ISA and inlet against published table values and closed forms."""

import numpy as np

from estimation.engine.atmosphere import P_SL, PSI, flight_condition, isa


def test_isa_table_values():
    # ICAO standard atmosphere table: (ft, K, Pa).
    table = [(0.0, 288.15, 101325.0), (10000.0, 268.338, 69681.7),
             (35000.0, 218.808, 23842.3), (40000.0, 216.65, 18753.9)]
    for alt, t_ref, p_ref in table:
        t, p = isa(alt)
        assert np.isclose(t, t_ref, atol=0.01)
        assert np.isclose(p, p_ref, rtol=2e-4)


def test_tropopause_is_continuous():
    h = 11000.0 / 0.3048
    t_lo, p_lo = isa(h - 1e-6)
    t_hi, p_hi = isa(h + 1e-6)
    assert np.isclose(t_lo, t_hi) and np.isclose(p_lo, p_hi)


def test_dtamb_shifts_temperature_not_pressure():
    t0, p0 = isa(20000.0)
    t1, p1 = isa(20000.0, 15.0)
    assert np.isclose(t1 - t0, 15.0) and np.isclose(p1, p0)


def test_inlet_ram_and_fd001_p2():
    fc = flight_condition(0.0, 0.0)
    assert np.isclose(fc.p2 / PSI, 14.62)  # C-MAPSS FD001 P2
    assert np.isclose(fc.t2 * 1.8, 518.67)  # C-MAPSS FD001 T2
    fc = flight_condition(35000.0, 0.8)
    # Isentropic stagnation: P2 / T2^3.5 is the static ratio times the recovery.
    ratio = (fc.p2 / fc.p_amb) / (fc.t2 / fc.t_amb) ** 3.5
    assert np.isclose(ratio, flight_condition(0.0, 0.0).p2 / P_SL)
    assert np.isclose(fc.v0, 0.8 * np.sqrt(1.4 * 287.05 * fc.t_amb))

"""The pipeline's trims on the built-in engine: the nominal engine's dense trim table, within a
tenth of the sensor noise of the exact steady-state solve over the whole envelope."""

import numpy as np

from app.services.snapshots import estimator
from estimation.engine.steady import ENVELOPE
from estimation.engine.trim_table import TRIM_AXIS_NAMES
from tests.estimation.engine.test_trim_table import exact, within_target


def test_the_builtin_table_is_within_a_tenth_of_the_noise_over_the_envelope():
    table = estimator.builtin_trim_table()
    assert table is not None
    rng = np.random.default_rng(17)
    c = np.column_stack([rng.uniform(*ENVELOPE[n], 1500) for n in TRIM_AXIS_NAMES])
    assert within_target(table.trims_at(c), exact(c)) == []


def test_the_schedule_takes_its_trims_from_the_table_inside_the_envelope_only():
    sched, table = estimator.builtin_schedule(), estimator.builtin_trim_table()
    assert table is not None
    p = {"alt": 35000.0, "mach": 0.8, "power": 80.0}
    model = sched.model_at(p["alt"], p["mach"], p["power"])
    schedule = estimator.engine_schedule_for(model, sched, table)
    # (alt, mach, dtamb, power): a cruise record, then one above the envelope's ceiling.
    c = np.array([[35000.0, 0.8, 5.0, 80.0], [41000.0, 0.8, 0.0, 80.0]])
    g = schedule(c)
    names = list(table.names)
    wanted = table.trims_at(c[:1])[0]
    for k, name in enumerate(model.sensor_names):
        assert g.y_trim[0, k] == wanted[names.index(name)]
    outside = sched.trims_at(c[1:, [0, 1, 3, 2]])
    for k, name in enumerate(model.sensor_names):
        assert g.y_trim[1, k] == outside[name][0]

"""The snapshot pipeline: the estimator of a design, the filter run (``run``), and the
database side (``store``: records in; estimates, events and filter states out)."""

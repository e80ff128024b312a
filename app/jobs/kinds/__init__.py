"""Job kinds of the service. Every module here registers its kinds on ``app.jobs.registry``.

Add a kind by adding a module to this package; ``load_kinds()`` imports them all.
"""

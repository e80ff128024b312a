"""Jobs as a service: submit, read and cancel jobs, and their schedules.

Routers and services queue work through ``queue.JobQueue`` (``Jobs`` in a route); the job
kinds and the runners that execute them live in ``app.jobs``, above this layer.
"""

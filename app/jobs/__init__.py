"""Job functions, their runners (in-process or Celery) and schedules."""

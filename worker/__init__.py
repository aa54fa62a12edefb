"""Celery workers: thin glue between the database/blob store and `learning/` + `sim/`.

Nothing imports this package except the Celery entry point (`celery -A worker.celery_app`) and the
`varbot worker` / `varbot models` commands.
"""

"""The method: audio front end, sound corpora, VAR, PPO, evaluation. No Celery, HTTP or database here."""

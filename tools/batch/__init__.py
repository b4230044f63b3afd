"""Batch runs: many captures, seeds or settings as tasks, on this machine's cores or a Ray
cluster, every failure retried once and reported."""

"""The `tofcut` command line (`cli`, `commands/`) and what it runs on: the tracking pipeline
(`pipeline/`), evaluation (`evaluation/`), experiments (`experiments/`) and benchmarks
(`bench/`)."""

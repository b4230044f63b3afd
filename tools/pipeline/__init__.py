"""The runtime that tracking runs on: sources opened by name, the belt a run knows, the
frame pipeline (feed → tracker → outputs) and its outputs (files, rerun, the conveyor)."""

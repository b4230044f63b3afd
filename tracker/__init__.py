"""Frames in, tracks out: graph-cut segmentation with range in the energy, and tracking."""

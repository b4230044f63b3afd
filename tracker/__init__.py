"""Frames in, tracks out: the multi-object tracker (graph-cut segmentation with range in the
energy, and tracking), and the paper's single-target segmentation in `tracker.paper`."""

"""ScanLocNet, scanloc's own learned localizer (beyond the paper): a classifier over cells of
the map's free space and heading bins with in-cell offsets (model.py, pose_grid.py), trained on
scans simulated afresh every epoch (scan_stream.py, training.py). Kept apart from models/ (the
paper's networks) so that the paper's trainings depend on none of it."""

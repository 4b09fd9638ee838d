"""What the paper's tables are made of, offline: the pipeline's rows over a labelled set and their
scores (`pipeline`, `tables`), pictures and plots of them (`draw`, `plot`), the tracker and
the IK on real motion (`tracking`, `ik`), and several people matched and tracked
(`tracking_metrics`: CLEAR-MOT, IDF1)."""

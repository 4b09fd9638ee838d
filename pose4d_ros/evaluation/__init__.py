"""What the paper's tables are made of, offline: the pipeline's rows over a labelled set and their
scores (`pipeline`, `tables`), pictures and plots of them (`draw`, `plot`), and the tracker and
the IK on real motion (`tracking`, `ik`)."""

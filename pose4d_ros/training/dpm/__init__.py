"""Training the 4D-DPM part model (`core.dpm`, which runs it): `train` (the steps and `train`
itself), `samples` (the settings, positives and background crops), `solver` (the structural
SVM's QP), `mining` (hard negatives) and `negatives` (the background images)."""

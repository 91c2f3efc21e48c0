//! Per-step metrics (paper eq:precision, eq:recall, eq:F1, no point adjustment), ROC/PR AUC, detection delay, false alarms per minute, mean and std over seeds.

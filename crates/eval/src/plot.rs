//! Plots with plotters: ROC curves, the F1-versus-amplitude sweep, the CUSUM post-attack plot and flight top views.

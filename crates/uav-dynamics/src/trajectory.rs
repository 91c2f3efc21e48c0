//! Reference trajectories: eight, UST letters, diagonal, square, formation square and random smooth routes.

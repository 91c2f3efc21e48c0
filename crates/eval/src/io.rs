//! File formats: CSV sensor streams, truth, labels and residue series; TOML configs; atomic writes.

//! Algorithm 1 (alg:alg1): run a Model I or Model II filter over aligned streams and record the residue series.

//! Algorithm 1 (alg:alg1) time-stamp alignment of multi-rate sensor streams.

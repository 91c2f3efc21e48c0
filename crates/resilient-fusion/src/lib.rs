//! Resilient state estimation (paper sec:state_estimation, alg:alg3) and closed-loop scenarios.
#![warn(missing_docs)]

//! The QUADFormer attack detector (paper sec:attack_detector, alg:alg2) in candle.
#![warn(missing_docs)]

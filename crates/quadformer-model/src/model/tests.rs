//! Unit tests of the QUADFormer network.
use super::*;

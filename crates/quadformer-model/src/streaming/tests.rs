//! The streaming engine against the candle forward pass it reorganises.

#![allow(clippy::unwrap_used)]

use candle_core::{Device, Tensor};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};

use super::*;
use crate::model::{ClassInput, GradFlow, NetConfig, Prior, QuadFormerNet, Steps};

const L: usize = 12;
const M: usize = 3;

/// The window that ends at residue `k` of `xs`, padded at the front with the first residue.
fn window(xs: &[Vec<f32>], k: usize) -> Tensor {
    let rows: Vec<f32> = (0..L).flat_map(|i| xs[(k + i + 1).saturating_sub(L)].clone()).collect();
    Tensor::from_vec(rows, (1, L, M), &Device::Cpu).unwrap()
}

fn residues(n: usize, seed: u64) -> Vec<Vec<f32>> {
    let mut rng = StdRng::seed_from_u64(seed);
    (0..n).map(|_| (0..M).map(|_| rng.random_range(-2.0f32..2.0)).collect()).collect()
}

/// A network with non-trivial biases, norms and TPC widths (the seeded initialisation leaves
/// biases at 0 and gains at 1, which would hide a misplaced bias).
fn network(cfg: &NetConfig, seed: u64) -> QuadFormerNet {
    let mut net = QuadFormerNet::new(cfg, L, M, seed).unwrap();
    let mut rng = StdRng::seed_from_u64(seed + 100);
    for (name, v) in net.varmap().data().lock().unwrap().iter() {
        let t = v.as_tensor();
        let noise: Vec<f32> = (0..t.elem_count()).map(|_| rng.random_range(-0.3f32..0.3)).collect();
        let noise = Tensor::from_vec(noise, t.shape(), &Device::Cpu).unwrap();
        if name.ends_with(".bias") || name.ends_with("log_gamma") || name.contains("norm") {
            v.set(&(t + noise).unwrap()).unwrap();
        }
    }
    net.freeze().unwrap();
    net
}

/// The candle pass's outputs for the newest step of the window that ends at residue `k`:
/// its logit, reconstruction error and the TCD of the window's steps. A full-window network
/// reads the padded window ([`window`]); a causal one that has seen fewer than `L` residues
/// reads them as the opening positions of a window (the rest repeats the newest) and scores
/// position `k`, as [`crate::detector::OnlineQuadFormer`]'s candle path does.
fn candle_newest(net: &QuadFormerNet, xs: &[Vec<f32>], k: usize, with_tcd: bool) -> (f32, f32, Vec<f32>) {
    let warm_up = net.config().causal && k + 1 < L;
    let (input, steps, row, seen) = if warm_up {
        let rows: Vec<f32> = (0..L).flat_map(|i| xs[i.min(k)].clone()).collect();
        (Tensor::from_vec(rows, (1, L, M), &Device::Cpu).unwrap(), Steps::All, k, k + 1)
    } else {
        (window(xs, k), Steps::Last { with_tcd }, 0, L)
    };
    let out = net.forward_steps(&input, steps).unwrap();
    let logit = out.logits.narrow(1, row, 1).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap()[0];
    let r_hat = out.r_hat.narrow(1, row, 1).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
    let err = r_hat.iter().zip(&xs[k]).map(|(r, v)| (r - v) * (r - v)).sum::<f32>() / M as f32;
    let tcd = if with_tcd {
        let tcd = QuadFormerNet::tcd(&out, GradFlow::Stop, GradFlow::Stop).unwrap();
        tcd.narrow(1, 0, seen).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap()
    } else {
        Vec::new()
    };
    (logit, err, tcd)
}

/// Streams `n` residues through the engine and compares every step with the candle pass.
fn agrees_with_candle(cfg: &NetConfig, with_tcd: bool) {
    let net = network(cfg, 7);
    assert_eq!(StreamingNet::unsupported(&net), None);
    let mut engine = StreamingNet::new(&net).unwrap();
    let xs = residues(2 * L + 5, 3);
    for (k, x) in xs.iter().enumerate() {
        let got = engine.push(x, with_tcd).unwrap();
        let (logit, err, want) = candle_newest(&net, &xs, k, with_tcd);
        assert!((got.logit - logit).abs() < 1e-4 * (1.0 + logit.abs()), "step {k}: logit {} vs {logit}", got.logit);
        assert!((got.recon_err - err).abs() < 1e-4 * (1.0 + err), "step {k}: error {} vs {err}", got.recon_err);
        match got.tcd {
            Some(tcd) => {
                assert_eq!(tcd.len(), want.len(), "step {k}");
                for (i, (a, b)) in tcd.iter().zip(&want).enumerate() {
                    assert!((a - b).abs() < 1e-5 + 1e-4 * b.abs(), "step {k}, row {i}: TCD {a} vs {b}");
                }
            }
            None => assert!(!with_tcd),
        }
    }
    assert_eq!(engine.n_seen(), xs.len());
}

fn small() -> NetConfig {
    NetConfig { d_model: 16, n_layers: 3, d_ff: 24, d_class: 8, ..NetConfig::default() }
}

#[test]
fn default_architecture_matches_candle_with_and_without_tcd() {
    agrees_with_candle(&small(), false);
    agrees_with_candle(&small(), true);
}

#[test]
fn several_heads_match_candle() {
    agrees_with_candle(&NetConfig { n_heads: 4, ..small() }, true);
    agrees_with_candle(&NetConfig { n_heads: 2, ..small() }, false);
}

#[test]
fn own_keys_without_dcm_match_candle() {
    agrees_with_candle(&NetConfig { dcm: false, ..small() }, true);
    agrees_with_candle(&NetConfig { dcm: false, n_heads: 2, ..small() }, false);
}

#[test]
fn gaussian_prior_matches_candle() {
    agrees_with_candle(&NetConfig { prior: Prior::Gaussian, n_heads: 2, ..small() }, true);
}

#[test]
fn reconstruction_input_and_other_depths_match_candle() {
    agrees_with_candle(&NetConfig { class_input: ClassInput::Reconstruction, ..small() }, true);
    agrees_with_candle(&NetConfig { n_layers: 1, ..small() }, true);
    agrees_with_candle(&NetConfig { n_layers: 1, ..small() }, false);
    agrees_with_candle(&NetConfig { n_layers: 2, p: 1.0, ..small() }, false);
    agrees_with_candle(&NetConfig { n_layers: 2, ..small() }, true);
    agrees_with_candle(&NetConfig { n_layers: 4, ..small() }, true);
    agrees_with_candle(&NetConfig { n_layers: 4, ..small() }, false);
}

#[test]
fn causal_attention_matches_candle_from_the_first_step() {
    for with_tcd in [true, false] {
        agrees_with_candle(&NetConfig { causal: true, ..small() }, with_tcd);
        agrees_with_candle(&NetConfig { causal: true, n_heads: 2, ..small() }, with_tcd);
        agrees_with_candle(&NetConfig { causal: true, dcm: false, ..small() }, with_tcd);
        agrees_with_candle(&NetConfig { causal: true, n_layers: 1, ..small() }, with_tcd);
    }
    agrees_with_candle(&NetConfig { causal: true, prior: Prior::Gaussian, n_heads: 2, ..small() }, true);
    agrees_with_candle(&NetConfig { causal: true, n_heads: 4, ..small() }, true);
    // The last layer on the newest row only: ring keys (layer 2) and projected scores (layer 1).
    agrees_with_candle(&NetConfig { causal: true, n_layers: 2, ..small() }, false);
    agrees_with_candle(&NetConfig { causal: true, n_heads: 4, n_layers: 1, ..small() }, false);
}

#[test]
fn reset_restarts_the_padding() {
    for cfg in [small(), NetConfig { causal: true, ..small() }] {
        let net = network(&cfg, 1);
        let mut engine = StreamingNet::new(&net).unwrap();
        let xs = residues(L + 3, 4);
        let first: Vec<f32> = xs.iter().map(|x| engine.push(x, false).unwrap().logit).collect();
        engine.reset();
        assert_eq!(engine.n_seen(), 0);
        let again: Vec<f32> = xs.iter().map(|x| engine.push(x, false).unwrap().logit).collect();
        assert_eq!(first, again);
    }
}

#[test]
fn bad_residues_are_errors() {
    let net = network(&small(), 1);
    let mut engine = StreamingNet::new(&net).unwrap();
    let e = engine.push(&[0.0; M + 1], false).err().unwrap();
    assert!(e.to_string().contains("residue of 4 values"), "{e}");
    let e = engine.push(&[0.0, f32::NAN, 0.0], true).err().unwrap();
    assert!(e.to_string().contains("channel 1"), "{e}");
    assert_eq!(engine.n_seen(), 0);
}

//! Unit tests of the QUADFormer network: shapes, TPC normalisation, Jensen–Shannon bounds,
//! gradient coverage and the stop-gradient split of the min-max phases.

use candle_core::Var;
use proptest::prelude::*;
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};

use super::*;
use crate::js::js_divergence;

fn tiny(prior: Prior, dcm: bool) -> NetConfig {
    NetConfig { d_model: 8, n_heads: 2, n_layers: 2, d_ff: 16, d_class: 4, prior, dcm, ..NetConfig::default() }
}

fn batch(b: usize, l: usize, m: usize, seed: u64) -> Batch {
    let mut rng = StdRng::seed_from_u64(seed);
    let x: Vec<f32> = (0..b * l * m).map(|_| rng.random_range(-1.0f32..1.0)).collect();
    let y: Vec<f32> = (0..b * l).map(|i| if i % 5 == 0 { 1.0 } else { 0.0 }).collect();
    let mask = vec![1f32; b * l];
    Batch {
        x: Tensor::from_vec(x, (b, l, m), &Device::Cpu).unwrap(),
        y: Tensor::from_vec(y, (b, l), &Device::Cpu).unwrap(),
        mask: Tensor::from_vec(mask, (b, l), &Device::Cpu).unwrap(),
        n_labelled: b * l,
    }
}

fn vars(net: &QuadFormerNet) -> Vec<(String, Var)> {
    let data = net.varmap().data().lock().unwrap();
    let mut v: Vec<(String, Var)> = data.iter().map(|(k, v)| (k.clone(), v.clone())).collect();
    v.sort_by(|a, b| a.0.cmp(&b.0));
    v
}

fn grad_norm(grads: &candle_core::backprop::GradStore, var: &Var) -> f32 {
    grads.get(var.as_tensor()).map_or(0.0, |g| g.abs().unwrap().sum_all().unwrap().to_scalar::<f32>().unwrap())
}

#[test]
fn output_shapes() {
    let net = QuadFormerNet::new(&tiny(Prior::Tpc, true), 12, 3, 0).unwrap();
    let out = net.forward(&batch(4, 12, 3, 1).x).unwrap();
    assert_eq!(out.r_hat.dims(), &[4, 12, 3]);
    assert_eq!(out.logits.dims(), &[4, 12]);
    assert_eq!(out.attn.len(), 2);
    assert_eq!(out.attn[0].dims(), &[4, 2, 12, 12]);
    assert_eq!(out.prior[1].dims(), &[1, 2, 12, 12]);
    assert_eq!(QuadFormerNet::tcd(&out, GradFlow::Pass, GradFlow::Pass).unwrap().dims(), &[4, 12]);
    assert!(net.forward(&batch(1, 11, 3, 1).x).is_err());
}

#[test]
fn last_step_forward_matches_the_full_forward() {
    let max_diff = |a: &Tensor, b: &Tensor| -> f32 {
        (a - b).unwrap().abs().unwrap().flatten_all().unwrap().max(0).unwrap().to_scalar::<f32>().unwrap()
    };
    for (prior, dcm, class_input, layers) in [
        (Prior::Tpc, true, ClassInput::Hidden, 3),
        (Prior::Tpc, false, ClassInput::Reconstruction, 2),
        (Prior::Gaussian, true, ClassInput::Reconstruction, 1),
        (Prior::Gaussian, false, ClassInput::Hidden, 3),
    ] {
        let cfg = NetConfig { class_input, n_layers: layers, ..tiny(prior, dcm) };
        let mut net = QuadFormerNet::new(&cfg, 12, 3, 5).unwrap();
        net.freeze().unwrap();
        let x = batch(3, 12, 3, 6).x;
        let full = net.forward(&x).unwrap();
        let tcd = QuadFormerNet::tcd(&full, GradFlow::Stop, GradFlow::Stop).unwrap();
        for with_tcd in [false, true] {
            let last = net.forward_steps(&x, Steps::Last { with_tcd }).unwrap();
            let case = format!("{prior:?} dcm={dcm} {class_input:?} layers={layers} tcd={with_tcd}");
            assert_eq!(last.r_hat.dims(), &[3, 1, 3], "{case}");
            assert_eq!(last.logits.dims(), &[3, 1], "{case}");
            assert!(max_diff(&last.r_hat, &full.r_hat.narrow(1, 11, 1).unwrap()) < 1e-5, "{case}");
            assert!(max_diff(&last.logits, &full.logits.narrow(1, 11, 1).unwrap()) < 1e-5, "{case}");
            if with_tcd {
                let t = QuadFormerNet::tcd(&last, GradFlow::Stop, GradFlow::Stop).unwrap();
                assert!(max_diff(&t, &tcd) < 1e-6, "{case}");
            } else {
                assert!(last.attn.is_empty() && last.prior.is_empty(), "{case}");
            }
        }
    }
}

#[test]
fn a_causal_network_reads_only_the_past() {
    let v = |t: &Tensor| t.flatten_all().unwrap().to_vec1::<f32>().unwrap();
    for (prior, dcm) in [(Prior::Tpc, true), (Prior::Tpc, false), (Prior::Gaussian, true)] {
        let cfg = NetConfig { causal: true, n_layers: 3, ..tiny(prior, dcm) };
        let mut net = QuadFormerNet::new(&cfg, 12, 3, 5).unwrap();
        let x = batch(1, 12, 3, 6).x;
        // Change the last four steps: the outputs of the first eight must not move.
        let later = (batch(1, 4, 3, 7).x * 5.0).unwrap();
        let y = Tensor::cat(&[x.narrow(1, 0, 8).unwrap(), later], 1).unwrap();
        let (a, b) = (net.forward(&x).unwrap(), net.forward(&y).unwrap());
        let case = format!("{prior:?} dcm={dcm}");
        let head = |t: &Tensor| v(&t.narrow(1, 0, 8).unwrap());
        assert_eq!(head(&a.r_hat), head(&b.r_hat), "{case}");
        assert_eq!(head(&a.logits), head(&b.logits), "{case}");
        assert_ne!(v(&a.logits), v(&b.logits), "{case}: the later steps must matter to themselves");
        // Priors and attention put no weight after the diagonal, and their rows sum to 1.
        for t in a.prior.iter().chain(&a.attn) {
            let rows = t.flatten_to(2).unwrap().to_vec2::<f32>().unwrap();
            for (r, row) in rows.iter().enumerate() {
                let i = r % 12;
                assert!(row[i + 1..].iter().all(|w| *w == 0.0), "{case}: row {i} {row:?}");
                assert!((row.iter().sum::<f32>() - 1.0).abs() < 1e-5, "{case}: row {i}");
            }
        }
        let tcd = QuadFormerNet::tcd(&a, GradFlow::Stop, GradFlow::Stop).unwrap();
        assert!(v(&tcd).iter().all(|t| t.is_finite() && *t >= 0.0), "{case}");
        // The last step's outputs, as streaming computes them, are the full pass's.
        net.freeze().unwrap();
        let full = net.forward(&x).unwrap();
        let last = net.forward_steps(&x, Steps::Last { with_tcd: false }).unwrap();
        let d = (last.logits - full.logits.narrow(1, 11, 1).unwrap()).unwrap().abs().unwrap();
        assert!(d.max_all().unwrap().to_scalar::<f32>().unwrap() < 1e-5, "{case}");
        // Every weight still learns, and the gradients are finite.
        net.thaw();
        assert_every_weight_learns(&net, &batch(3, 12, 3, 2), &case);
    }
    // A configuration written before the field existed reads as the paper's full-window attention.
    let mut json = serde_json::to_value(tiny(Prior::Tpc, true)).unwrap();
    json.as_object_mut().unwrap().remove("causal");
    assert!(!serde_json::from_value::<NetConfig>(json).unwrap().causal);
}

#[test]
fn prior_rows_sum_to_one_and_peak_on_diagonal() {
    for prior in [Prior::Tpc, Prior::Gaussian] {
        let net = QuadFormerNet::new(&tiny(prior, true), 30, 2, 0).unwrap();
        let out = net.forward(&batch(2, 30, 2, 3).x).unwrap();
        for t in &out.prior {
            let sums = t.sum(D::Minus1).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
            assert!(sums.iter().all(|s| (s - 1.0).abs() < 1e-5), "{prior:?}: {sums:?}");
            let rows = t.flatten_to(2).unwrap().to_vec2::<f32>().unwrap();
            for (i, row) in rows.iter().enumerate() {
                let i = i % 30;
                assert!(row.iter().all(|v| *v <= row[i] + 1e-7 && v.is_finite() && *v >= 0.0));
            }
        }
    }
}

#[test]
fn every_parameter_receives_gradient() {
    let cases = [
        (Prior::Tpc, true, ClassInput::Hidden),
        (Prior::Tpc, false, ClassInput::Hidden),
        (Prior::Gaussian, true, ClassInput::Hidden),
        (Prior::Tpc, true, ClassInput::Reconstruction),
    ];
    for (prior, dcm, class_input) in cases {
        let net = QuadFormerNet::new(&NetConfig { class_input, ..tiny(prior, dcm) }, 10, 3, 5).unwrap();
        assert_every_weight_learns(&net, &batch(3, 10, 3, 2), &format!("{prior:?} dcm={dcm} {class_input:?}"));
    }
}

/// One training loss's gradient reaches every weight of `net` and is finite. With DCM the last
/// layer's keys feed no later layer and its queries attend to the previous layer's keys, so its
/// own `w_k` is unused (eq:cross_layer_attention).
fn assert_every_weight_learns(net: &QuadFormerNet, b: &Batch, case: &str) {
    let trainer = MinMaxTrainer { net, loss: LossConfig::default() };
    let grads = nn_toolkit::train::TrainableModel::loss(&trainer, b, 0).unwrap().backward().unwrap();
    let unused = format!("layers.{}.attn.w_k", net.config().n_layers - 1);
    for (name, var) in vars(net) {
        if net.config().dcm && name.starts_with(&unused) {
            continue;
        }
        let g = grad_norm(&grads, &var);
        assert!(g > 0.0 && g.is_finite(), "{case}: gradient {g} reaches {name}");
    }
}

#[test]
fn min_max_phases_split_gradients_like_anomaly_transformer() {
    let net = QuadFormerNet::new(&tiny(Prior::Tpc, true), 10, 3, 9).unwrap();
    let terms = net.loss_terms(&batch(2, 10, 3, 4), &LossConfig::default()).unwrap();
    let g_min = terms.dis_min.backward().unwrap();
    let g_max = terms.dis_max.backward().unwrap();
    for (name, var) in vars(&net) {
        let (gmin, gmax) = (grad_norm(&g_min, &var), grad_norm(&g_max, &var));
        if name.ends_with("log_gamma") {
            assert!(gmin > 0.0, "min phase must move γ ({name})");
            assert_eq!(gmax, 0.0, "max phase must not move the detached prior ({name})");
        } else if name.contains("w_q") || name.starts_with("embed") {
            assert_eq!(gmin, 0.0, "min phase must not move the detached attention ({name})");
            assert!(gmax > 0.0, "max phase must move the attention ({name})");
        }
    }
    // Both phases see the same TCD value.
    let a = terms.dis_min.to_scalar::<f32>().unwrap();
    let b = terms.dis_max.to_scalar::<f32>().unwrap();
    assert_eq!(a, b);
}

#[test]
fn summed_loss_has_the_value_and_gradient_of_both_phases() {
    for prior in [Prior::Tpc, Prior::Gaussian] {
        let net = QuadFormerNet::new(&tiny(prior, true), 10, 3, 9).unwrap();
        let (b, cfg) =
            (batch(3, 10, 3, 4), LossConfig { lambda: 3.0, alpha1: 0.7, alpha2: 1.3, ..LossConfig::default() });
        let terms = net.loss_terms(&b, &cfg).unwrap();
        let two = (terms.max_phase(&cfg).unwrap() + terms.min_phase(&cfg).unwrap()).unwrap();
        let one = net.summed_min_max_loss(&b, &cfg).unwrap();
        let (v2, v1) = (two.to_scalar::<f32>().unwrap(), one.to_scalar::<f32>().unwrap());
        assert!((v1 - v2).abs() <= 1e-5 * v2.abs(), "{prior:?}: value {v1} against {v2}");
        let (g2, g1) = (two.backward().unwrap(), one.backward().unwrap());
        for (name, var) in vars(&net) {
            let (Some(a), Some(b)) = (g2.get(var.as_tensor()), g1.get(var.as_tensor())) else {
                assert!(g2.get(var.as_tensor()).is_none() && g1.get(var.as_tensor()).is_none(), "{name}");
                continue;
            };
            let scale = a.abs().unwrap().max_all().unwrap().to_scalar::<f32>().unwrap().max(1e-6);
            let diff = (a - b).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f32>().unwrap();
            assert!(diff <= 1e-4 * scale, "{prior:?} {name}: gradients differ by {diff} (scale {scale})");
        }
    }
}

#[test]
fn class_head_input_sizes_and_old_configs() {
    let hidden = QuadFormerNet::new(&tiny(Prior::Tpc, true), 10, 3, 0).unwrap();
    let recon =
        QuadFormerNet::new(&NetConfig { class_input: ClassInput::Reconstruction, ..tiny(Prior::Tpc, true) }, 10, 3, 0)
            .unwrap();
    // class1 reads d_model = 8 values per step from the hidden state, m = 3 from R̂.
    assert_eq!(hidden.n_params() - recon.n_params(), (8 - 3) * 4);
    // A configuration written before the field existed reads as the paper's head.
    let mut json = serde_json::to_value(tiny(Prior::Tpc, true)).unwrap();
    json.as_object_mut().unwrap().remove("class_input");
    let old: NetConfig = serde_json::from_value(json).unwrap();
    assert_eq!(old.class_input, ClassInput::Reconstruction);
}

#[test]
fn same_seed_same_network() {
    let x = batch(2, 10, 3, 1).x;
    let a = QuadFormerNet::new(&tiny(Prior::Tpc, true), 10, 3, 11).unwrap().forward(&x).unwrap();
    let b = QuadFormerNet::new(&tiny(Prior::Tpc, true), 10, 3, 11).unwrap().forward(&x).unwrap();
    let c = QuadFormerNet::new(&tiny(Prior::Tpc, true), 10, 3, 12).unwrap().forward(&x).unwrap();
    let v = |t: &Tensor| t.flatten_all().unwrap().to_vec1::<f32>().unwrap();
    assert_eq!(v(&a.r_hat), v(&b.r_hat));
    assert_ne!(v(&a.r_hat), v(&c.r_hat));
}

#[test]
fn frozen_network_matches_training_forward() {
    let mut net = QuadFormerNet::new(&tiny(Prior::Tpc, true), 10, 3, 11).unwrap();
    let x = batch(2, 10, 3, 1).x;
    let a = net.forward(&x).unwrap().logits.flatten_all().unwrap().to_vec1::<f32>().unwrap();
    net.freeze().unwrap();
    let b = net.forward(&x).unwrap().logits.flatten_all().unwrap().to_vec1::<f32>().unwrap();
    // Fused inference kernels round differently from the differentiable ones.
    assert!(a.iter().zip(&b).all(|(u, v)| (u - v).abs() < 1e-4), "{a:?} vs {b:?}");
}

#[test]
fn bce_matches_definition() {
    let z = Tensor::new(&[[0.0f32, 2.0, -3.0]], &Device::Cpu).unwrap();
    let y = Tensor::new(&[[1.0f32, 0.0, 0.0]], &Device::Cpu).unwrap();
    let mask = Tensor::new(&[[1.0f32, 1.0, 0.0]], &Device::Cpu).unwrap();
    let got = masked_bce_with_logits(&z, &y, &mask, 2, 1.0).unwrap().to_scalar::<f32>().unwrap();
    let sig = |v: f64| 1.0 / (1.0 + (-v).exp());
    let want = (-(sig(0.0).ln()) - (1.0 - sig(2.0)).ln()) / 2.0;
    assert!((f64::from(got) - want).abs() < 1e-6, "{got} vs {want}");
}

#[test]
fn weighted_bce_weighs_attacked_steps() {
    let z = Tensor::new(&[[0.5f32, 2.0, -3.0]], &Device::Cpu).unwrap();
    let y = Tensor::new(&[[1.0f32, 0.0, 1.0]], &Device::Cpu).unwrap();
    let mask = Tensor::new(&[[1.0f32, 1.0, 1.0]], &Device::Cpu).unwrap();
    let got = masked_bce_with_logits(&z, &y, &mask, 3, 4.0).unwrap().to_scalar::<f32>().unwrap();
    let sig = |v: f64| 1.0 / (1.0 + (-v).exp());
    let want = (-4.0 * sig(0.5).ln() - (1.0 - sig(2.0)).ln() - 4.0 * sig(-3.0).ln()) / 3.0;
    assert!((f64::from(got) - want).abs() < 1e-5, "{got} vs {want}");
}

fn distribution(raw: &[f64]) -> Vec<f32> {
    let s: f64 = raw.iter().sum();
    raw.iter().map(|v| (v / s) as f32).collect()
}

proptest! {
    #[test]
    fn js_is_symmetric_nonnegative_and_bounded(
        a in proptest::collection::vec(0.0f64..1.0, 8),
        b in proptest::collection::vec(0.0f64..1.0, 8),
        spike in 0usize..8,
    ) {
        let mut a = a;
        a[spike] += 1e-3;
        let mut b = b;
        b[(spike + 3) % 8] += 1e-3;
        let p = Tensor::new(distribution(&a), &Device::Cpu).unwrap();
        let q = Tensor::new(distribution(&b), &Device::Cpu).unwrap();
        let pq = js_divergence(&p, &q).unwrap().to_scalar::<f32>().unwrap();
        let qp = js_divergence(&q, &p).unwrap().to_scalar::<f32>().unwrap();
        let pp = js_divergence(&p, &p).unwrap().to_scalar::<f32>().unwrap();
        prop_assert!((pq - qp).abs() < 1e-6);
        prop_assert!(pq >= -1e-7);
        prop_assert!(pq <= std::f32::consts::LN_2 + 1e-6);
        prop_assert!(pp.abs() < 1e-6);
    }

    #[test]
    fn js_of_disjoint_supports_is_ln2(k in 1usize..7) {
        let mut a = vec![0.0f64; 8];
        let mut b = vec![0.0f64; 8];
        a[..k].iter_mut().for_each(|v| *v = 1.0);
        b[k..].iter_mut().for_each(|v| *v = 1.0);
        let js = js_divergence(&Tensor::new(distribution(&a), &Device::Cpu).unwrap(), &Tensor::new(distribution(&b), &Device::Cpu).unwrap())
            .unwrap().to_scalar::<f32>().unwrap();
        prop_assert!((js - std::f32::consts::LN_2).abs() < 1e-5);
    }
}

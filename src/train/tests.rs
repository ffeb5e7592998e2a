//! The tensor right-hand side against the vehicle module, and weight export round trips.

use super::*;
use crate::model::{Architecture, PincModel, Provenance};
use crate::types::{Input, State};
use crate::vehicle::{self, VehicleParams};
use burn::prelude::*;

fn batch(rows: &[[f64; 9]], device: &Device) -> Tensor<2> {
    let flat: Vec<f32> = rows.iter().flat_map(|r| r.iter().map(|&v| v as f32)).collect();
    Tensor::from_data(TensorData::new(flat, [rows.len(), 9]), device)
}

#[test]
fn tensor_rhs_matches_the_vehicle_model() {
    let device = Device::flex();
    let p = VehicleParams::default();
    let states = [
        [0.3, -0.1, 1.2, 0.8, 0.6, 0.4, -0.15, 0.2, -0.3],
        [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        [-2.0, 1.0, 0.5, -0.6, -0.8, -0.5, 0.25, -0.3, 0.5],
    ];
    let inputs = [[3.0, -1.0, 6.0, 0.2], [0.0, 0.0, 0.0, 0.0], [-10.0, 5.0, 20.0, -1.0]];
    let x = batch(&states, &device);
    let uflat: Vec<f32> = inputs.iter().flat_map(|r| r.iter().map(|&v| v as f32)).collect();
    let u = Tensor::<2>::from_data(TensorData::new(uflat, [3, 4]), &device);
    let got = super::to_f32(rhs(&p, x, u));
    for (i, (s, f)) in states.iter().zip(&inputs).enumerate() {
        let want = vehicle::rhs(&p, &State::from(*s), &Input::from(*f));
        for k in 0..9 {
            let g = f64::from(got[i * 9 + k]);
            assert!((g - want[k]).abs() <= 1e-5 * want[k].abs().max(1.0), "row {i} component {k}: {g} vs {}", want[k]);
        }
    }
}

#[test]
fn exported_weights_round_trip_through_the_frozen_format() {
    let device = Device::flex();
    let arch = Architecture::paper(4, 32);
    let net = PincNet::init(&arch, 7, &device);
    let model = PincModel {
        architecture: arch.clone(),
        dt: 0.08,
        input_scaling: None,
        output_scaling: None,
        envelope: None,
        provenance: Provenance::default(),
        weights: net.weights(),
        vehicle: crate::vehicle::VehicleParams::default(),
        hybrid: None,
        fitted: None,
    };
    crate::model::validate(&model).unwrap();
    let again = PincNet::from_model(&model, &device);
    assert_eq!(again.weights(), model.weights);
    // Xavier bounds and the documented initial values.
    let w0 = &model.weights.hidden[0];
    let limit = (6.0 / (14.0 + 32.0_f64)).sqrt() as f32;
    assert!(w0.linear.weight.iter().all(|w| w.abs() <= limit));
    assert!(w0.linear.bias.iter().all(|b| *b == 0.0) && w0.beta == 1.0);
    // Seeded: the same seed gives the same weights, another seed others.
    assert_eq!(PincNet::init(&arch, 7, &device).weights(), model.weights);
    assert_ne!(PincNet::init(&arch, 8, &device).weights(), model.weights);
}

#[test]
fn a_lagged_step_with_fresh_coefficients_is_the_per_loss_combination() {
    // One backward pass of sum_n a_n L_n equals the scheme's combination of the per-loss
    // gradients when a_n come from those gradients: what a lagged step reuses is exact at the
    // step that measured it, for every scheme.
    use crate::dataset::{DatasetPreset, generate_set};
    use rand::SeedableRng;
    let device = Device::flex().autodiff();
    let mut spec = DatasetPreset::paper().set("train").unwrap().clone();
    spec.count = 3;
    let set = generate_set(&spec, &VehicleParams::default(), 5, || {});
    let mut cfg = TrainConfig::paper();
    cfg.rollout_steps = 5;
    cfg.rollout_stride = 7;
    let net = PincNet::init(&cfg.architecture, 3, &device);
    let params = VehicleParams::default();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2);
    let batch = Batch::new(&set, &[0, 1, 2], &cfg, &mut rng, &device);
    let grads: Vec<Vec<f32>> =
        cfg.losses.iter().map(|&k| trainer::flatten(&net, &loss(k, &net, &params, &batch).backward())).collect();
    for scheme in [GradCombine::Sum, GradCombine::Normalize, GradCombine::Config] {
        let want = combine(scheme, &grads, &cfg.weights);
        let a = coefficients(scheme, &grads, &cfg.weights);
        let (total, values) = joint_losses(&cfg, &net, &params, &batch, &a);
        assert!(values.iter().all(Option::is_some), "{scheme:?}: a loss left out");
        let got = trainer::flatten(&net, &total.backward());
        let scale = want.iter().map(|v| v.abs()).fold(0.0f32, f32::max);
        for (i, (g, w)) in got.iter().zip(&want).enumerate() {
            assert!((g - w).abs() <= 1e-4 * scale, "{scheme:?} parameter {i}: {g} vs {w} (max |g| {scale})");
        }
    }
    // A zero weight leaves the loss out of the graph.
    let mut w = cfg.weights.clone();
    w[1] = 0.0;
    let (_, values) = joint_losses(&cfg, &net, &params, &batch, &w);
    assert!(values[1].is_none() && values[0].is_some());
}
